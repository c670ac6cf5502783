"""The MJX pushing environment behind the learner's `EnvAdapter`: masks in, latents out.

Each environment step's object mask is encoded once, here, on device; the goal mask once per episode.
The actor only ever sees the 6-number latents and the noisy flange xy. The learner also gets the
ground-truth object and goal xy that rewards and HER relabelling need, and ``priv``, the simulator's
state for a privileged critic and the scripted expert (`PRIV_LAYOUT`). An environment whose episode
went invalid (NaN, object through or off the table) reports it through `episode_invalid`; the learner
stores that episode as invalid and never samples it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjx_push import encoder as enc
from mjx_push import expert as expert_mod
from mjx_push.batch import BatchState, PushBatch
from mjx_push.env import EnvConfig
from mjx_push.train.adapter import EnvAdapter, SubstepScheduler
from mjx_push.errors import ConfigError

# The privileged state, per environment step: name -> width, in order. The object's xy comes first
# (the learner's convention: priv[:2] is the achieved goal).
PRIV_LAYOUT = (
    ("object_xy", 2),
    ("object_yaw_cos_sin", 2),
    ("object_vel", 3),
    ("ee_xy", 2),
    ("ee_vel", 2),
    ("size", 3),
    ("is_box", 1),
    ("log_mass", 1),
    ("friction", 1),
)
PRIV_DIM = sum(w for _, w in PRIV_LAYOUT)


def _slices() -> dict[str, slice]:
    out, i = {}, 0
    for name, w in PRIV_LAYOUT:
        out[name] = slice(i, i + w)
        i += w
    return out


PRIV = _slices()


def privileged_state(s: BatchState, is_box: jax.Array) -> jax.Array:
    """[N, PRIV_DIM] ground truth of every environment (never observed by the actor)."""
    params = s.info["params"]
    yaw = s.info["object_yaw"]
    parts = {
        "object_xy": s.info["object_xy"],
        "object_yaw_cos_sin": jnp.stack([jnp.cos(yaw), jnp.sin(yaw)], -1),
        "object_vel": s.info["object_vel"],
        "ee_xy": s.info["ee_xy_true"],
        "ee_vel": s.info["ee_vel"],
        "size": params.size,
        "is_box": is_box.astype(jnp.float32)[:, None],
        "log_mass": jnp.log(params.mass)[:, None],
        "friction": params.friction[:, :1],
    }
    return jnp.concatenate([parts[name] for name, _ in PRIV_LAYOUT], axis=-1)


def expert_ground_truth(priv: jax.Array, goal_xy: jax.Array) -> dict:
    """The scripted expert's inputs (mjx_push.expert.act) read back from the privileged state."""
    cs = priv[..., PRIV["object_yaw_cos_sin"]]
    return {
        "ee_xy": priv[..., PRIV["ee_xy"]],
        "object_xy": priv[..., PRIV["object_xy"]],
        "object_yaw": jnp.arctan2(cs[..., 1], cs[..., 0]),
        "goal_xy": goal_xy,
        "size": priv[..., PRIV["size"]],
        "is_box": priv[..., PRIV["is_box"]][..., 0] > 0.5,
    }


# Substeps per scheduler tick: each environment takes its next action as soon as its own step's a_s
# substeps are spent, instead of every step waiting for the slowest environment
# (benchmarks/rollout_throughput.py measures the effect of this value).
DEFAULT_SUBSTEP_CHUNK = 50
# The protocol's shape filter (mjx_push.train.episodes.SHAPES) for a training shape filter (objects.SHAPE_FILTERS).
EVAL_SHAPE = {
    "any": "all",
    "cylinder": "cylinder",
    "cuboid": "cuboid",
    "square": "square",
    "rectangular": "rectangular",
}


def run_adapter(run, encoder_params, substep_chunk: int = DEFAULT_SUBSTEP_CHUNK) -> EnvAdapter:
    """The pushing scene's adapter for a run configuration `run` (a RunConfig): its environment and
    expert. A data-parallel run (`train.loop.data_parallel` > 1) keeps each batch on one device, since
    every device steps its own share of the environments (`make_train` refuses a batch split over
    devices there); otherwise a batch is split over the host devices."""
    max_devices = 1 if run.train.loop.data_parallel > 1 else None
    return make_push_adapter(run.env, encoder_params, substep_chunk, run.expert, max_devices=max_devices)


def make_push_adapter(
    env_config: EnvConfig,
    encoder_params,
    substep_chunk: int = DEFAULT_SUBSTEP_CHUNK,
    expert_config: expert_mod.ExpertConfig = expert_mod.ExpertConfig(),
    max_devices: int | None = None,
    shapes: tuple[str, ...] | None = None,
) -> EnvAdapter:
    """Adapter over `PushBatch(env_config, n, max_devices, shapes)`; one batch object is built per
    environment count `n`. `substep_chunk` 0 steps all environments in lockstep: the episodes start as
    a chunk's but part within a few steps (another order of float operations, and a step's substep
    count is an integer); any two chunks above 0 give the same episodes. The adapter's expert is
    `mjx_push.expert` under `expert_config`. `max_devices` 1 keeps
    every batch on one device (a data-parallel run's per-device share); `shapes` builds only those
    shape groups (a group's own program: its evaluation episodes come from the whole batch's adapter)."""
    if not (isinstance(substep_chunk, int) and substep_chunk >= 0):
        raise ConfigError(f"substep_chunk must be an integer >= 0 (0: lockstep), got {substep_chunk!r}")
    batches: dict[int, PushBatch] = {}

    def batch(n: int) -> PushBatch:
        if n not in batches:
            # Built on first use, often while a function is being traced: its model and constants must
            # be concrete arrays, not tracers of that one trace, since later traces reuse the batch.
            with jax.ensure_compile_time_eval():
                batches[n] = PushBatch(env_config, n, max_devices, shapes)
        return batches[n]

    def is_box(s: BatchState) -> jax.Array:
        b = batch(s.num_envs)
        return jnp.asarray([g == "box" for g in b.geom_types])[b.shape_ids]

    def observe(s: BatchState) -> dict:
        obs = s.obs
        return {
            "ee_xy": obs["ee_xy"],
            "z_obj": enc.encode(encoder_params, obs["object_mask"]),
            "obj_xy": s.info["object_xy"],
            "priv": privileged_state(s, is_box(s)),
        }

    def expert(step_obs: dict, info: dict) -> jax.Array:
        gt = expert_ground_truth(step_obs["priv"], info["goal_xy"])
        return jax.vmap(lambda g: expert_mod.act(expert_config, env_config, g))(gt)

    def reset(key: jax.Array, num_envs: int, episodes: dict | None = None):
        s = batch(num_envs).reset(key, episodes)
        info = {"z_goal": enc.encode(encoder_params, s.obs["goal_mask"]), "goal_xy": s.info["goal_xy"]}
        return s, observe(s), info

    def step(s: BatchState, action: jax.Array):
        s = batch(action.shape[0]).step(s, action)
        return s, observe(s), s.info["episode_invalid"]

    def begin(s: BatchState, action: jax.Array, mask: jax.Array) -> BatchState:
        return batch(action.shape[0]).begin(s, action, mask)

    def advance(s: BatchState, max_substeps: int) -> BatchState:
        return batch(s.num_envs).advance(s, max_substeps)

    def ready(s: BatchState) -> jax.Array:
        return batch(s.num_envs).ready(s)

    def finish(s: BatchState, mask: jax.Array):
        s = batch(mask.shape[0]).finish(s, mask)
        return s, observe(s), s.info["episode_invalid"]

    def eval_episodes(setting: str, seed: int, chunk: int, num_envs: int) -> dict:
        """Chunk `chunk` of the protocol's episodes (mjx_push.train.episodes.episode_objects) of `setting` and
        `seed`, laid out as a batch of `num_envs`: with both shapes the box group runs the even
        (cuboid) episodes and the cylinder group the odd ones, as the protocol splits them, so with
        equal groups chunk c is exactly episodes [c N, (c + 1) N)."""
        from mjx_push.train.episodes import EvalSpec, episode_objects  # the protocol (imports the learner's modules)

        b = batch(num_envs)
        spec = EvalSpec(setting=setting, shape=EVAL_SHAPE[env_config.objects.shape], seed=seed)
        keys, params, index = [], [], []
        for geom_type, count in zip(b.geom_types, b.counts):
            slots = chunk * count + np.arange(count)
            idx = 2 * slots + (geom_type != "box") if len(b.counts) == 2 else slots
            p, k = episode_objects(spec, env_config.objects, geom_type, idx)
            params.append(p)
            keys.append(k)
            index.append(idx)
        cat = lambda *xs: jnp.concatenate(xs)  # noqa: E731
        return {
            "use": np.asarray(True),
            "keys": cat(*keys),
            "params": jax.tree.map(cat, *params),
            "index": np.concatenate(index),
        }

    scheduler = SubstepScheduler(begin, advance, ready, finish, substep_chunk) if substep_chunk else None

    def one_device(adapter: EnvAdapter, group: int | None = None) -> EnvAdapter | None:
        """This environment with every batch on one device (only shape group `group`'s environments
        when given), for `adapter` if it is this one's own environment (a copy with its reset, step,
        scheduler or expert replaced gets None)."""
        if (adapter.reset, adapter.step, adapter.scheduler, adapter.expert) != (reset, step, scheduler, expert):
            return None
        part = None if group is None else (env_config.objects.shapes()[group],)
        return make_push_adapter(env_config, encoder_params, substep_chunk, expert_config, max_devices=1, shapes=part)

    return EnvAdapter(
        reset=reset,
        step=step,
        success_tau=env_config.success_tau,
        episode_len=env_config.episode_length,
        scheduler=scheduler,
        priv_dim=PRIV_DIM,
        expert=expert,
        mesh=lambda n: batch(n).mesh,
        one_device=None if max_devices == 1 else one_device,
        groups=lambda n: batch(n).counts,
        eval_episodes=eval_episodes if shapes is None else None,
    )

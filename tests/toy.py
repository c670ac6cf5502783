"""A tiny goal-reaching task behind the same ``EnvAdapter`` as the MJX pushing environment.

A point "object" in the plane moves directly with the action: obj_xy += step_size * action[:2],
clipped to the box [-bound, bound]^2 (a_s is ignored). The end effector sits on the object. The
object and goal are observed only through a fixed random linear map into 6 latent dimensions (seeded),
so, as with the real encoder, the agent must read the goal through a latent code. Start and goal are
uniform in the box. It exercises the whole SAC + HER pipeline in seconds on a CPU. Its privileged
state is the object's xy, and its expert steps straight at the goal.
"""

from __future__ import annotations

import flax.struct
import jax
import jax.numpy as jnp

from mjx_push.train.adapter import EnvAdapter, SubstepScheduler, select_envs
from mjx_push.train.config import AgentConfig, DemoConfig, LoopConfig, ReplayConfig, SACConfig, TrainConfig

TAU = 0.025  # the toy's success radius in the learning tests and checks (the real task's is 0.01)


@flax.struct.dataclass
class ToyState:
    obj_xy: jax.Array  # [N, 2]
    key: jax.Array  # [N, 2], per environment: drives the optional random invalid flags
    pending: jax.Array  # [N, 2] the move of the step in progress (scheduled stepping only)
    left: jax.Array  # [N] substeps left in it


def latent_map(seed: int, bound: float) -> jax.Array:
    """[2, 6] matrix with z = xy @ M; scaled so latent codes are O(1), like an encoder's."""
    return jax.random.normal(jax.random.PRNGKey(seed), (2, 6)) / bound


def make_toy(
    success_tau: float = 0.025,
    episode_len: int = 10,
    step_size: float = 0.05,
    bound: float = 0.15,
    seed: int = 0,
    invalid_prob: float = 0.0,
    substep_chunk: int = 0,
    max_substeps: int = 8,
) -> EnvAdapter:
    """The toy adapter. ``success_tau`` and ``episode_len`` are the task's success radius and episode
    length, which the learner reads from the adapter (it computes rewards from ``obj_xy`` / ``goal_xy``
    at that radius). ``invalid_prob`` flags random steps invalid, to exercise the handling of broken
    simulations. A larger tolerance than the real task's 1 cm keeps learning fast in tests.

    ``substep_chunk`` > 0 gives the adapter a ``SubstepScheduler``: a step then lasts 1..``max_substeps``
    substeps chosen by a_s, like the pushing task's, and the move lands when they are spent, so the
    learner's scheduled rollout can be checked against the lockstep one on a task that compiles in
    seconds."""
    M = latent_map(seed, bound)

    def observe(obj_xy):
        return {"ee_xy": obj_xy, "z_obj": obj_xy @ M, "obj_xy": obj_xy, "priv": obj_xy}

    def expert(step_obs, info):
        a = jnp.clip((info["goal_xy"] - step_obs["priv"]) / step_size, -1.0, 1.0)
        return jnp.concatenate([a, jnp.ones_like(a[:, :1])], axis=1)

    def reset(key, num_envs):
        k_obj, k_goal, k_state = jax.random.split(key, 3)
        obj = jax.random.uniform(k_obj, (num_envs, 2), minval=-bound, maxval=bound)
        goal = jax.random.uniform(k_goal, (num_envs, 2), minval=-bound, maxval=bound)
        state = ToyState(
            obj, jax.random.split(k_state, num_envs), jnp.zeros((num_envs, 2)), jnp.zeros((num_envs,), jnp.int32)
        )
        return state, observe(obj), {"z_goal": goal @ M, "goal_xy": goal}

    def step(state, action):
        obj = jnp.clip(state.obj_xy + step_size * jnp.clip(action[:, :2], -1.0, 1.0), -bound, bound)
        key, k_bad = jnp.swapaxes(jax.vmap(jax.random.split)(state.key), 0, 1)
        invalid = jax.vmap(jax.random.uniform)(k_bad) < invalid_prob
        return state.replace(obj_xy=obj, key=key), observe(obj), invalid

    def begin(state, action, mask):
        n = 1 + jnp.floor((jnp.clip(action[:, 2], -1.0, 1.0) + 1.0) / 2.0 * (max_substeps - 1)).astype(jnp.int32)
        return select_envs(mask, state.replace(pending=action[:, :2], left=n), state)

    def advance(state, chunk):
        return state.replace(left=jnp.maximum(state.left - chunk, 0))

    def finish(state, mask):
        new, _, invalid = step(state, jnp.concatenate([state.pending, jnp.zeros_like(state.pending[:, :1])], 1))
        state = select_envs(mask, new, state)
        return state, observe(state.obj_xy), invalid & mask

    scheduler = None
    if substep_chunk:
        scheduler = SubstepScheduler(begin, advance, lambda s: s.left == 0, finish, substep_chunk)
    return EnvAdapter(
        reset=reset,
        step=step,
        success_tau=success_tau,
        episode_len=episode_len,
        scheduler=scheduler,
        priv_dim=2,
        expert=expert,
    )


def toy_config(kind, total_env_steps, seed=0, hidden=(128, 256, 64), batch_size=128, **loop):
    """Plain SAC + HER on the toy task; its episodes last the toy's episode_len (10 unless made
    otherwise). At 1,600 (VPM) or 1,920 (uGRU) env steps it learns the task
    (`benchmarks/learning_checks.py`)."""
    loop = {
        "num_envs": 8,
        "total_env_steps": total_env_steps,
        "warmup_env_steps": 480,
        "utd": 1.0,
        "eval_every_env_steps": 800,
        "eval_episodes": 100,
        "seed": seed,
        **loop,
    }
    return TrainConfig(
        agent=AgentConfig(kind, hidden=hidden),
        sac=SACConfig(batch_size=batch_size),
        replay=ReplayConfig(capacity_transitions=20_000),
        loop=LoopConfig(**loop),
    )


def all_features_config(loop_over=None, **over):
    """Every learner feature at once on the toy task (normalisation, privileged critic with layer
    norm, target clipping, cloning from demonstrations, the radius curriculum); at 1,280 env steps it
    learns the task (`benchmarks/learning_checks.py`)."""
    loop = dict(
        num_envs=8,
        total_env_steps=1280,
        warmup_env_steps=160,
        utd=1.0,
        eval_every_env_steps=640,
        eval_episodes=100,
        seed=0,
    )
    loop.update(loop_over or {})
    return TrainConfig(
        agent=AgentConfig("vpm", obs_norm=True, critic_obs="privileged", critic_layer_norm=True),
        sac=SACConfig(batch_size=128, init_alpha=0.05, target_clip=True, bc_weight=1.0, bc_batch_size=64),
        replay=ReplayConfig(capacity_transitions=20_000, curriculum_tau=0.05, curriculum_env_steps=400),
        loop=LoopConfig(**loop),
        demo=DemoConfig(warmup=True, fraction=0.25, noise=0.1),
        **over,
    )

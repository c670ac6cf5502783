"""The paper's evaluation protocol on the MJX scene (docs/task.md section 7).

Deterministic policy; `episodes` test episodes per setting and shape, drawn from fixed seeds that do
not depend on the policy, so every agent meets the same objects, starts and goals: episode i's object
is `objects.sample(fold_in(PRNGKey(seed), i), ...)` and its observation noise key likewise. Metrics
per setting: success rate (final distance < tau), mean episode reward (sum of the 50 sparse rewards),
mean overshoot and distance corrections (counted per 1 ms substep by the environment), each with its
standard error of the mean; and the mean object-goal distance at the start and the end.

Settings: "standard" (Table I), "difficult" (the paper's figure: mass U[0.001, 0.01], sliding friction
U[0.2, 0.3], minimum full height 0.052), or "custom" with the ranges given. Shapes: "cylinder",
"square", "rectangular", or "all" (the episode index decides: even -> cuboid, odd -> cylinder, so the
split is exact and independent of the batch size).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mjx_push import encoder as enc
from mjx_push import expert as expert_mod
from mjx_push import devices, objects, scene
from mjx_push.env import EnvConfig, PushEnv
from train.networks import make_networks
from train.presets import RunConfig
from train.policies import Policy
from mjx_push.errors import ConfigError

SETTINGS = ("standard", "difficult", "custom")
SHAPES = ("all", "cylinder", "square", "rectangular", "cuboid")
METRICS = ("success", "reward", "overshoot", "distance")  # the paper's
# Object-goal distance (m) at reset and at the end: progress the sparse metrics cannot show (while no
# episode ends within 1 cm, every reward is -50). Invalid episodes count as no progress.
DISTANCE_METRICS = ("start_distance", "final_distance")
DIFFICULT = dict(mass=(0.001, 0.01), friction=(0.2, 0.3), min_height=0.052)
# `mjx-push eval` (MJX) and `mjx-push deploy` (CPU MuJoCo) print the same table (train.eval_options holds
# their shared options).
METRIC_LABELS = {
    "success": "success rate",
    "reward": "mean episode reward",
    "overshoot": "overshoot corrections",
    "distance": "distance corrections",
    "start_distance": "object-goal distance at reset (m)",
    "final_distance": "object-goal distance at the end (m)",
}


def metrics_table(title: str, summary: dict):
    """A rich Table of `summarize`'s output: each metric's mean, SEM and episode count."""
    from rich.table import Table

    table = Table(title=title)
    for col in ("metric", "mean", "SEM", "n"):
        table.add_column(col, justify="right")
    for key, label in METRIC_LABELS.items():
        if key in summary:
            m = summary[key]
            table.add_row(label, f"{m['mean']:.3f}", f"{m['sem']:.3f}", str(m["n"]))
    return table


@dataclasses.dataclass(frozen=True)
class EvalSpec:
    setting: str = "difficult"
    shape: str = "all"
    episodes: int = 100
    seed: int = 1_000_003  # distinct from training seeds; shared by every agent
    batch: int = 20  # episodes simulated in parallel (does not change the episodes)
    mass: tuple[float, float] | None = None  # custom setting: ranges replacing Table I's
    friction: tuple[float, float] | None = None
    min_height: float | None = None
    record: int = 0  # keep the per-step trajectories of the first `record` episodes (for videos)
    success_tau: float | None = None  # success radius (m) to score at; None: the one the policy trained for

    def __post_init__(self):
        if self.setting not in SETTINGS:
            raise ConfigError(f"setting must be one of {SETTINGS}, got {self.setting!r}")
        if self.shape not in SHAPES:
            raise ConfigError(f"shape must be one of {SHAPES}, got {self.shape!r}")
        if not (isinstance(self.episodes, int) and self.episodes > 0):
            raise ConfigError(f"episodes must be a positive integer, got {self.episodes!r}")
        if not (isinstance(self.batch, int) and self.batch > 0):
            raise ConfigError(f"batch must be a positive integer, got {self.batch!r}")
        custom = any(v is not None for v in (self.mass, self.friction, self.min_height))
        if custom and self.setting != "custom":
            raise ConfigError("mass / friction / min_height ranges need setting 'custom'")
        if not 0 <= self.record <= self.episodes:
            raise ConfigError(f"record must be in [0, episodes], got {self.record}")
        if self.success_tau is not None and not (math.isfinite(self.success_tau) and self.success_tau > 0):
            raise ConfigError(f"success_tau must be a positive number of metres, got {self.success_tau!r}")

    def object_config(self, base: objects.ObjectConfig | None = None) -> objects.ObjectConfig:
        """The object distribution; uniform sampling whatever the agent trained on."""
        cfg = dataclasses.replace(base or objects.ObjectConfig(), mode="uniform")
        if self.setting == "difficult":
            cfg = dataclasses.replace(cfg, **DIFFICULT)
        elif self.setting == "custom":
            fields = {
                k: v
                for k, v in (("mass", self.mass), ("friction", self.friction), ("min_height", self.min_height))
                if v is not None
            }
            cfg = dataclasses.replace(cfg, **fields)
        return cfg


def sem(x: np.ndarray) -> float:
    """Standard error of the mean: sample standard deviation (ddof=1) / sqrt(n); 0 for one sample."""
    x = np.asarray(x, dtype=np.float64)
    return float(np.std(x, ddof=1) / math.sqrt(len(x))) if len(x) > 1 else 0.0


def summarize(per_episode: dict) -> dict:
    """{metric: {"mean", "sem", "n"}} over per-episode arrays: the paper's METRICS, and the
    DISTANCE_METRICS present."""
    keys = METRICS + tuple(k for k in DISTANCE_METRICS if k in per_episode)
    # float64 whatever the input: a fresh evaluation (float32 arrays) and one read back from JSON (Python
    # floats) of the same episodes must give the same summary.
    return {
        k: {
            "mean": float(np.mean(np.asarray(per_episode[k], np.float64))),
            "sem": sem(per_episode[k]),
            "n": int(len(per_episode[k])),
        }
        for k in keys
    }


def episode_geom_type(shape: str, i: int) -> str:
    """The geom type of episode `i` under shape filter `shape` ("all": even cuboids, odd cylinders)."""
    if shape == "all":
        return ("box", "cylinder")[i % 2]
    return "cylinder" if shape == "cylinder" else "box"


def episode_objects(spec: EvalSpec, base: objects.ObjectConfig, geom_type: str, indices: np.ndarray):
    """(ObjectParams, environment keys) of episodes `indices` (all of `geom_type`): episode i's object,
    start and goal are drawn from fold_in(PRNGKey(spec.seed), i) alone, so every policy and both
    simulators (MJX here, CPU MuJoCo in `mjx-push deploy`) meet the same episodes."""
    cfg = dataclasses.replace(spec.object_config(base), shape=_filter(spec.shape, geom_type))
    home = jnp.asarray(scene.home_flange_pos()[:2], jnp.float32)
    base_key = jax.random.PRNGKey(spec.seed)
    keys = jax.vmap(lambda i: jax.random.fold_in(base_key, i))(jnp.asarray(indices))
    k_obj = jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys)
    k_env = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    params = jax.vmap(lambda k: objects.sample(k, cfg, geom_type, home))(k_obj)
    return params, k_env


def _geom_types(shape: str) -> tuple[str, ...]:
    return {"all": ("box", "cylinder"), "cylinder": ("cylinder",)}.get(shape, ("box",))


def _filter(shape: str, geom_type: str) -> str:
    if shape == "all":
        return "cuboid" if geom_type == "box" else "cylinder"
    return shape


@dataclasses.dataclass(frozen=True)
class ExpertPolicy:
    """The environment's scripted expert (mjx_push.expert) as something to evaluate: it reads the
    simulator's ground truth, so it is a baseline, not a deployable policy. ``config`` gives the action
    box (``config.env``) and the expert's settings (``config.expert``)."""

    config: RunConfig
    scores: dict = dataclasses.field(default_factory=dict)
    actor_params: Any = None
    encoder_params: Any = None


class Evaluator:
    """Compiled episode runners for one environment config and agent kind (or the scripted expert
    when ``expert_config`` is given); reusable across policies and settings of the same shapes (the
    objects are inputs, not constants)."""

    def __init__(
        self, env_config: EnvConfig, agent_config, batch: int, expert_config: expert_mod.ExpertConfig | None = None
    ):
        self.env_config = env_config
        self.expert_config = expert_config
        self.nets = None if expert_config is not None else make_networks(agent_config)
        self.batch = batch
        self._envs: dict[str, PushEnv] = {}
        self._fns: dict[str, Any] = {}

    def env(self, geom_type: str) -> PushEnv:
        if geom_type not in self._envs:
            cfg = dataclasses.replace(
                self.env_config,
                objects=dataclasses.replace(
                    self.env_config.objects, shape="cylinder" if geom_type == "cylinder" else "cuboid"
                ),
            )
            self._envs[geom_type] = PushEnv(cfg, geom_type)
        return self._envs[geom_type]

    def episode_fn(self, geom_type: str):
        if geom_type in self._fns:
            return self._fns[geom_type]
        env, nets, T = self.env(geom_type), self.nets, self.env_config.episode_length
        expert_cfg = self.expert_config
        # The episodes of a batch are split over the devices (one per core on a CPU) like training's.
        mesh = devices.env_mesh((self.batch,))
        reset_with, step = devices.shard(jax.vmap(env.reset_with), mesh), devices.shard(jax.vmap(env.step), mesh)

        def run(actor_params, encoder_params, params, keys):
            s = reset_with(keys, params)
            qpos0 = s.pipeline_state.qpos
            if expert_cfg is not None:

                def policy(s, carry):
                    gt = expert_mod.ground_truth(s.info, params.size, jnp.full(keys.shape[0], geom_type == "box"))
                    return jax.vmap(lambda g: expert_mod.act(expert_cfg, env.config, g))(gt), carry

                carry0 = jnp.zeros((keys.shape[0], 0))
            else:
                z_goal = enc.encode(encoder_params, s.info["goal_mask"])

                def policy(s, carry):
                    obs = {
                        "ee_xy": s.obs["ee_xy"],
                        "z_obj": enc.encode(encoder_params, s.obs["object_mask"]),
                        "z_goal": z_goal,
                    }
                    return nets.act(actor_params, carry, obs, jax.random.PRNGKey(0), True)

                carry0 = nets.init_carry(keys.shape[0])

            def body(c, _):
                s, carry = c
                action, carry = policy(s, carry)
                s = step(s, action)
                return (s, carry), (s.reward, s.pipeline_state.qpos, action, s.info["substeps"])

            (s, _), (rewards, qpos, actions, substeps) = jax.lax.scan(body, (s, carry0), None, length=T)
            dist = jnp.linalg.norm(s.info["object_xy"] - s.info["goal_xy"], axis=-1)
            start_dist = jnp.linalg.norm(params.start[:, :2] - params.goal[:, :2], axis=-1)
            invalid = s.info["episode_invalid"]
            return {
                "success": (~invalid & (dist < env.config.success_tau)).astype(jnp.float32),
                "reward": jnp.where(invalid, -float(T), jnp.sum(rewards, axis=0)),
                "overshoot": s.info["corrections"].overshoot.astype(jnp.float32),
                "distance": s.info["corrections"].distance.astype(jnp.float32),
                "start_distance": start_dist,
                "final_distance": jnp.where(invalid, start_dist, dist),
                "invalid": invalid,
                "mean_substeps": jnp.mean(substeps.astype(jnp.float32), axis=0),  # simulation cost per step
                "qpos": jnp.concatenate([qpos0[None], qpos], axis=0).swapaxes(0, 1),  # [B, T+1, nq]
                "action": actions.swapaxes(0, 1),
                "substeps": substeps.swapaxes(0, 1),
            }

        self._fns[geom_type] = jax.jit(run)
        return self._fns[geom_type]

    def episode_params(self, spec: EvalSpec, geom_type: str, indices: np.ndarray):
        return episode_objects(spec, self.env_config.objects, geom_type, indices)

    def evaluate(self, policy: Policy, spec: EvalSpec) -> dict:
        """Per-episode arrays (in episode order) and their summary."""
        per: dict[str, list] = {}
        order: list[np.ndarray] = []
        recorded: list[dict] = []
        for geom_type in _geom_types(spec.shape):
            idx = np.arange(spec.episodes)
            if spec.shape == "all":
                idx = idx[idx % 2 == (0 if geom_type == "box" else 1)]
            fn = self.episode_fn(geom_type)
            for start in range(0, len(idx), self.batch):
                chunk = idx[start : start + self.batch]
                pad = self.batch - len(chunk)  # keep one compiled batch size
                padded = np.concatenate([chunk, np.repeat(chunk[-1:], pad)])
                params, keys = self.episode_params(spec, geom_type, padded)
                out = jax.device_get(fn(policy.actor_params, policy.encoder_params, params, keys))
                for k, v in out.items():
                    if k in ("qpos", "action", "substeps"):
                        continue
                    per.setdefault(k, []).append(np.asarray(v)[: len(chunk)])
                for j, i in enumerate(chunk):
                    if i < spec.record:
                        recorded.append(
                            {
                                "episode": int(i),
                                "geom_type": geom_type,
                                "params": jax.tree.map(lambda a: np.asarray(a[j]), params),
                                "qpos": out["qpos"][j],
                                "action": out["action"][j],
                                "substeps": out["substeps"][j],
                            }
                        )
                order.append(chunk)
        perm = np.argsort(np.concatenate(order), kind="stable")
        arrays = {k: np.concatenate(v)[perm] for k, v in per.items()}
        return {
            "per_episode": arrays,
            "summary": summarize(arrays),
            "invalid_episodes": int(np.sum(arrays["invalid"])),
            "recorded": sorted(recorded, key=lambda r: r["episode"]),
        }


def evaluator_for(
    env_config: EnvConfig, agent_config, batch: int, expert_config: expert_mod.ExpertConfig | None = None
) -> Evaluator:
    """A shared Evaluator per (environment, agent network or expert, batch): compiled once per process.
    Keyed by what changes compiled code only: evaluations draw their own objects (uniformly, whatever
    the training sampler), uGRU and eGRU share one network, and the expert needs no network."""
    env = dataclasses.replace(env_config, objects=dataclasses.replace(env_config.objects, mode="uniform"))
    if expert_config is not None:
        agent_config = None
    elif agent_config.kind == "egru":
        agent_config = dataclasses.replace(agent_config, kind="ugru")
    return _cached_evaluator(env, agent_config, batch, expert_config)


@functools.lru_cache(maxsize=8)
def _cached_evaluator(env_config: EnvConfig, agent_config, batch: int, expert_config) -> Evaluator:
    return Evaluator(env_config, agent_config, batch, expert_config)


def evaluate(policy: Policy | ExpertPolicy, spec: EvalSpec) -> dict:
    """Evaluate a trained policy (or the scripted expert) under ``spec``, at ``spec.success_tau`` if
    given, else at the radius the policy trained for."""
    env = policy.config.env
    if spec.success_tau is not None:
        env = dataclasses.replace(env, success_tau=spec.success_tau)
    expert = policy.config.expert if isinstance(policy, ExpertPolicy) else None
    ev = evaluator_for(env, policy.config.train.agent, min(spec.batch, spec.episodes), expert)
    return ev.evaluate(policy, spec)

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

from mjx_push import task_rules
from mjx_push import encoder as enc
from mjx_push import expert as expert_mod
from mjx_push import devices
from mjx_push.env import EnvConfig, PushEnv
from mjx_push.perturb import PerturbConfig
from mjx_push.train.episodes import EvalSpec, episode_objects, geom_types
from mjx_push.train.networks import make_networks
from mjx_push.train.config import RunConfig
from mjx_push.train.runs.policies import Policy

METRICS = ("success", "reward", "overshoot", "distance")  # the paper's
# Object-goal distance (m) at reset and at the end: progress the sparse metrics cannot show (while no
# episode ends within 1 cm, every reward is -50). Invalid episodes count as no progress.
DISTANCE_METRICS = ("start_distance", "final_distance")
# `mjx-push eval` (MJX) and `mjx-push deploy` (CPU MuJoCo) print the same table (mjx_push.cli.options holds
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
                "success": (~invalid & task_rules.reached(dist, env.config.success_tau)).astype(jnp.float32),
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
        for geom_type in geom_types(spec.shape):
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
    the training sampler) and run without the training's perturbations (`env.perturb`), uGRU and eGRU share one network, and the expert needs no network."""
    # The protocol's episodes are clean whatever the policy trained under (train/stress.py perturbs them).
    env = dataclasses.replace(
        env_config, objects=dataclasses.replace(env_config.objects, mode="uniform"), perturb=PerturbConfig()
    )
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

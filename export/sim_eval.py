"""Run an exported policy in `CpuPushEnv` for the evaluation protocol (docs/task.md section 7; used by
`mjx-push deploy`).

Settings, shapes and episodes are those of `mjx-push eval` (`mjx_push.train.evaluate`): episode i's object, start
and goal come from `mjx_push.train.episodes.episode_objects(spec, ..., [i])`, so the MJX evaluation and this one
score a policy on the same episodes; with shape "all" even episodes are cuboids and odd ones cylinders.
Observation noise is drawn from seed + i. An invalid episode (NaN, object off or through the table)
counts as a failure with the worst reward, as in training's evaluation.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable

import numpy as np

from mjx_push.config import EnvConfig
from mjx_push.perturb import PerturbConfig

VIDEO_HEIGHT = 192
VIDEO_SIZES = {"top": (VIDEO_HEIGHT, 256), "under_table": (VIDEO_HEIGHT, VIDEO_HEIGHT)}


def env_config(metadata: dict, spec, perturb: PerturbConfig | None = None) -> EnvConfig:
    """The task the policy was trained on (controller, solver, action mapping from the exported run
    configuration) with the objects of the evaluation `spec` (a `mjx_push.train.episodes.EvalSpec`),
    clean whatever the policy trained under, or with the perturbations `perturb` (a real cell's,
    docs/robustness.md)."""
    from mjx_push.train import configio

    try:
        base = configio.from_dict(EnvConfig, metadata["run_config"]["env"], "env")
    except (KeyError, TypeError, ValueError) as e:
        # An export from another mjx-push version: keep what the policy's action mapping needs.
        warnings.warn(
            f"the policy's run configuration does not fit this mjx-push ({e}); using default "
            "controller and solver settings",
            RuntimeWarning,
            stacklevel=2,
        )
        a, task = metadata["action"], metadata["task"]
        base = EnvConfig(
            action_scale=a["action_scale"],
            substeps=tuple(a["substeps"]),
            workspace_x=tuple(a["workspace_x"]),
            workspace_y=tuple(a["workspace_y"]),
            episode_length=task["episode_length"],
            success_tau=task["success_tau"],
        )
    objects_cfg = spec.object_config(base.objects)
    shape = "any" if spec.shape == "all" else spec.shape
    return dataclasses.replace(
        base, objects=dataclasses.replace(objects_cfg, shape=shape), perturb=perturb or PerturbConfig()
    )


def run_cpu(
    policy, spec, mask_source: str, success_tau: float | None = None, perturb: PerturbConfig | None = None
) -> list[dict]:
    """`run_episodes` of a `NumpyPolicy` in a `CpuPushEnv` of `env_config(policy.metadata, spec, perturb)`
    with `mask_source` masks, scored at `success_tau` (default: the radius the policy trained for)."""
    from mjx_push.export.cpu_env import CpuPushEnv

    config = env_config(policy.metadata, spec, perturb)
    if success_tau is not None:
        config = dataclasses.replace(config, success_tau=success_tau)
    env = CpuPushEnv(config, mask_source=mask_source)
    try:
        return run_episodes(policy, env, spec)
    finally:
        env.close()


GOAL_TINT = np.array([0, 90, 0], np.uint8)  # goal silhouette drawn faintly green in the under-table view


def side_by_side(env) -> np.ndarray:
    """One video frame: the top view and the under-table view (goal silhouette tinted), side by side."""
    top = env.render_rgb("top", VIDEO_SIZES["top"])
    under = env.render_rgb("under_table", VIDEO_SIZES["under_table"])
    scale = VIDEO_HEIGHT // env.goal_mask.shape[0]
    goal = np.kron(env.goal_mask, np.ones((scale, scale), bool))  # nearest upsampling of the 64x64 mask
    background = under.max(axis=-1) < 30
    under[goal & background] = GOAL_TINT
    return np.concatenate([top, under], axis=1)


def run_episodes(policy, env, spec, on_frame: Callable[[int, object], None] | None = None) -> list[dict]:
    """`spec.episodes` deterministic episodes of `policy` (an object with `reset()` and
    `act_raw(object_mask, goal_mask, ee_xy)`) in `env` (a `CpuPushEnv` built from `env_config`), the
    episodes of the MJX evaluation with the same `spec`. `on_frame(episode, env)` is called after the
    reset and after every step (for videos). Returns one record per episode."""
    from mjx_push.train.episodes import episode_geom_type, episode_objects

    steps = env.config.episode_length
    geoms = [episode_geom_type(spec.shape, i) for i in range(spec.episodes)]
    params = {}  # episode -> ObjectParams (NumPy), drawn per geom type in one call
    for geom in sorted(set(geoms)):
        idx = np.array([i for i, g in enumerate(geoms) if g == geom])
        p, _ = episode_objects(spec, env.config.objects, geom, idx)
        for j, i in enumerate(idx):
            params[int(i)] = type(p)(**{k: np.asarray(getattr(p, k))[j] for k in p.__dataclass_fields__})
    records = []
    for i in range(spec.episodes):
        policy.reset()
        obs = env.reset(seed=spec.seed + i, params=params[i], geom_type=geoms[i])
        start_distance = env.info()["distance"]
        if on_frame is not None:
            on_frame(i, env)
        reward = 0.0
        for _ in range(steps):
            action = policy.act_raw(obs["object_mask"], obs["goal_mask"], obs["ee_xy"])
            obs, r, _, _, info = env.step(action)  # the env decodes a_s exactly as the policy's act() does
            reward += r
            if on_frame is not None:
                on_frame(i, env)
        valid = not info["episode_invalid"]
        records.append(
            {
                "episode": i,
                "seed": spec.seed + i,
                "geom_type": info["geom_type"],
                "success": bool(info["success"]) and valid,
                "reward": reward if valid else -float(steps),
                "overshoot": int(info["corrections"].overshoot),
                "distance": int(info["corrections"].distance),
                "start_distance": float(start_distance),
                "final_distance": float(info["distance"]) if valid else float(start_distance),
                "valid": valid,
                "bad_actions": int(info["bad_actions"]),
            }
        )
    return records

"""Run an exported policy in `CpuPushEnv` for the SPEC section 7 protocol (used by `mjx-push deploy`).

Settings: "standard" is Table I (uniform mass and friction, for every agent alike); "difficult" is the
paper's figure: mass U[0.001, 0.01], sliding friction U[0.2, 0.3], minimum full height 0.052. Episode i
is seeded with `seed + i`, so every policy meets the same objects. An invalid episode (NaN, object off or
through the table) counts as a failure with the worst reward, as in training's evaluation.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable

import numpy as np

from mjx_push import objects
from mjx_push.env import EnvConfig

SETTINGS = ("standard", "difficult")
VIDEO_HEIGHT = 192
VIDEO_SIZES = {"top": (VIDEO_HEIGHT, 256), "under_table": (VIDEO_HEIGHT, VIDEO_HEIGHT)}


def object_config(setting: str, shape: str) -> objects.ObjectConfig:
    if setting not in SETTINGS:
        raise ValueError(f"setting must be one of {SETTINGS}, got {setting!r}")
    if shape not in objects.SHAPE_FILTERS:
        raise ValueError(f"shape must be one of {objects.SHAPE_FILTERS}, got {shape!r}")
    from train.evaluate import DIFFICULT  # one definition of the paper's difficult case (MJX and CPU)

    extra = DIFFICULT if setting == "difficult" else {}
    return objects.ObjectConfig(mode="uniform", shape=shape, **extra)


def env_config(metadata: dict, setting: str, shape: str) -> EnvConfig:
    """The task the policy was trained on (controller, solver, action mapping from the exported run
    configuration) with the objects of the evaluation setting."""
    from train import configio

    try:
        base = configio.from_dict(EnvConfig, metadata["run_config"]["env"], "env")
    except (KeyError, TypeError, ValueError) as e:
        # An export from another mjx-push version: keep what the policy's action mapping needs.
        warnings.warn(f"the policy's run configuration does not fit this mjx-push ({e}); using default "
                      "controller and solver settings", RuntimeWarning, stacklevel=2)
        a, task = metadata["action"], metadata["task"]
        base = EnvConfig(action_scale=a["action_scale"], substeps=tuple(a["substeps"]),
                         workspace_x=tuple(a["workspace_x"]), workspace_y=tuple(a["workspace_y"]),
                         episode_length=task["episode_length"], success_tau=task["success_tau"])
    return dataclasses.replace(base, objects=object_config(setting, shape))


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


def run_episodes(policy, env, episodes: int, seed: int,
                 on_frame: Callable[[int, object], None] | None = None) -> list[dict]:
    """`episodes` deterministic episodes of `policy` (an object with `reset()` and `act_raw(object_mask,
    goal_mask, ee_xy)`) in `env` (a `CpuPushEnv`). `on_frame(episode, env)` is called after the reset and
    after every step (for videos). Returns one record per episode."""
    records = []
    steps = env.config.episode_length
    for i in range(episodes):
        policy.reset()
        obs = env.reset(seed=seed + i)
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
        records.append({
            "episode": i,
            "seed": seed + i,
            "geom_type": info["geom_type"],
            "success": bool(info["success"]) and valid,
            "reward": reward if valid else -float(steps),
            "overshoot": int(info["corrections"].overshoot),
            "distance": int(info["corrections"].distance),
            "final_distance": float(info["distance"]),
            "valid": valid,
            "bad_actions": int(info["bad_actions"]),
        })
    return records

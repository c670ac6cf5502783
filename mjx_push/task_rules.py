"""The task's per-step rules, written once over an array module `xp` (NumPy or jax.numpy).

The MJX environment (`mjx_push.env`, `mjx_push.corrections`) calls these with `xp=jax.numpy` under jit,
the CPU MuJoCo environment and the deployment loop (`mjx_push.export.cpu_env`, `mjx_push.export.corrections_np`,
`mjx_push.export.deploy`, `mjx_push.export.numpy_policy`) with NumPy, the default. They use no Python control flow on
array values, so they trace under `jit`/`vmap`, and compute in their inputs' floating type: NumPy callers
keep float64, except `decode_substeps`, which they call on float32 (the JAX environment's type) so that
both sides give the same count.

This module imports no JAX (`tests/test_deploy_imports.py`).
"""

from __future__ import annotations

import numpy as np

TAU = 0.01  # success radius (m): an episode succeeds when the object is closer than this to its goal
EPS = 2e-5  # dead band (m) of the correction counters


def decode_substeps(a_s, substeps: tuple[int, int], *, xp=np):
    """a_s in [-1, 1] -> integer substeps in [low, high] (linear, truncated), int32, evaluated in a_s's
    floating type (pass float32 for the MJX environment's count)."""
    lo, hi = substeps
    n = xp.floor(lo + (xp.clip(a_s, -1.0, 1.0) + 1.0) * 0.5 * (hi - lo))
    return xp.clip(n, lo, hi).astype(xp.int32)


def substep_count(a_s, substeps: tuple[int, int]) -> int:
    """`decode_substeps` as a Python int, in float32 whatever a_s's type (NumPy callers: the CPU
    environment and the exported policy), so it equals the MJX environment's count."""
    return int(decode_substeps(np.float32(a_s), substeps))


def sanitize_action(action, *, xp=np):
    """Documented clip: non-finite components become 0 and the rest are clipped to [-1, 1].
    Returns the action and whether anything was non-finite (a 0-d bool)."""
    finite = xp.isfinite(action)
    return xp.clip(xp.where(finite, action, 0.0), -1.0, 1.0), ~xp.all(finite)


def flange_target(ee_xy, a_xy, action_scale: float, workspace_x, workspace_y, home_z, *, xp=np):
    """The flange target (3,) of an action: ee_xy + a_xy * action_scale clipped to the workspace, z at
    the home flange height."""
    xy = xp.asarray(ee_xy, dtype=float)[:2] + xp.asarray(a_xy, dtype=float)[:2] * action_scale
    z = xp.asarray(home_z, dtype=xy.dtype)
    return xp.stack([xp.clip(xy[0], *workspace_x), xp.clip(xy[1], *workspace_y), z])


def yaw_quat(yaw, *, xp=np):
    """Quaternion (w, x, y, z) (4,) of a rotation by `yaw` about the world z axis."""
    return xp.stack([xp.cos(yaw / 2), 0.0 * yaw, 0.0 * yaw, xp.sin(yaw / 2)])


def quat_yaw(q, *, xp=np):
    """Yaw (rad) of quaternion `q` (w, x, y, z)."""
    w, x, y, z = q
    return xp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def reached(dist, tau: float = TAU):
    """The task's success: the object's centre strictly closer than `tau` to the goal's (boolean). Every
    scorer asks this (the environments, the learner's rewards and statistics, the evaluators)."""
    return dist < tau


def sparse_reward(dist, tau: float = TAU):
    """The task's reward for a step ending at object-goal distance `dist`: 0 once reached, else -1."""
    return reached(dist, tau) * 1.0 - 1.0


def correction_events(d_prev, flag, d, tau: float = TAU, eps: float = EPS, *, xp=np):
    """One substep of the correction counters (docs/task.md section 7), with d_prev the distance at the
    previous substep (+inf after reset) and `flag` whether it has grown since the last distance
    correction. Returns (overshoot, distance correction, new flag), bools:

    - overshoot: d_prev < tau and d >= tau and |d - tau| > eps;
    - distance: the flag is set when d > d_prev + eps; while it is set, d < d_prev - eps counts one
      correction and clears it.

    Non-finite distances never count (every comparison with NaN is false)."""
    # Operators and the builtin abs only, but for one logical_not (`~` on a Python bool is an int): on
    # the CPU side these are Python floats and bools at every 1 ms substep, where NumPy calls cost.
    over = (d_prev < tau) & (d >= tau) & (abs(d - tau) > eps)
    grew = d > d_prev + eps
    shrank = d < d_prev - eps
    counted = flag & shrank
    return over, counted, (flag | grew) & xp.logical_not(counted)


def object_bounds(size, geom_type: str, *, xp=np):
    """Bounding-sphere radius and axis-aligned half extents (3,) of the object geom with MJCF size
    `size` (3,), which MuJoCo's collision culling reads from the model."""
    if geom_type == "box":
        return xp.linalg.norm(size), size
    return xp.sqrt(size[0] ** 2 + size[1] ** 2), xp.stack([size[0], size[0], size[1]])

"""NumPy port of `mjx_push.controller.joint_velocity` for CPU MuJoCo (`mujoco.MjData`).

Identical math: task error [tilt rows ; p_d - p_ee], Jacobian rows over joints 1-6 at the flange of link 7,
damped pseudo-inverse, hold gain on the tilt and height rows, clipping to the velocity limits and to the
distance left to each joint limit, times the safety scale. Both tilt laws ("axis", "dot") are ported.
The configuration is the same `ControllerConfig` the MJX environment uses. `law` takes plain arrays
(flange pose, Jacobians, joint positions) so that a real robot adapter can run the very same law at 1 kHz
with its own kinematics (see docs/deploy.md).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from mjx_push import scene
from mjx_push.controller import ControllerConfig

C_AXIS = np.array([0.0, 0.0, -1.0])
_EYE = {4: np.eye(4), 5: np.eye(5)}


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # np.cross costs ~70 us per call through its axis handling; this runs at every 1 ms substep.
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def flange_pose(d: mujoco.MjData, ids: scene.SceneIds) -> tuple[np.ndarray, np.ndarray]:
    """Flange position (3,) and z axis (3,) from the data's kinematics (copies)."""
    return d.site_xpos[ids.flange_site].copy(), d.site_xmat[ids.flange_site].reshape(3, 3)[:, 2].copy()


def law(
    p: np.ndarray,
    z: np.ndarray,
    jac_pos: np.ndarray,
    jac_rot: np.ndarray,
    q: np.ndarray,
    target: np.ndarray,
    cfg: ControllerConfig,
) -> np.ndarray:
    """The task-space velocity law on plain arrays, so a real robot can run it with its own kinematics.

    p, z: flange position and z axis (3,) in the base frame; jac_pos, jac_rot: (3, 6) linear and angular
    Jacobians of the flange over joints 1-6 in the base frame; q: (7,) joint positions; target: (3,)
    desired flange position. Returns the desired joint velocities (7,) (joint 7 stays still)."""
    if cfg.tilt_law == "dot":
        j_tilt = (_cross(C_AXIS, z) @ jac_rot)[None]  # c^T [z]x J_rot
        e_tilt = np.array([C_AXIS @ z - 1.0])
    else:
        j_tilt = cfg.tilt_weight * jac_rot[:2]  # world x, y angular velocity
        e_tilt = cfg.tilt_weight * _cross(z, C_AXIS)[:2]
    jac = np.concatenate([j_tilt, jac_pos], axis=0)  # (4 or 5, 6)
    e_pos = (np.asarray(target, np.float64) - p) * np.array([1.0, 1.0, cfg.hold_gain])
    err = np.concatenate([cfg.hold_gain * e_tilt, e_pos])
    gram = jac @ jac.T + cfg.damping**2 * _EYE[jac.shape[0]]
    dq = cfg.gain * (jac.T @ np.linalg.solve(gram, err))
    dq = np.concatenate([dq, np.zeros(1)])
    # Velocity limits and the distance left to each position limit (a joint outside its range may only
    # move back in), as in the MJX law.
    lo = np.maximum(-scene.VELOCITY_LIMIT, scene.JOINT_RANGE[:, 0] - q)
    hi = np.minimum(scene.VELOCITY_LIMIT, scene.JOINT_RANGE[:, 1] - q)
    dq = np.minimum(np.maximum(dq, lo), hi)
    return dq * cfg.safety_scale


def joint_velocity(
    m: mujoco.MjModel, d: mujoco.MjData, target: np.ndarray, ids: scene.SceneIds, cfg: ControllerConfig
) -> np.ndarray:
    """Desired joint velocities (7,) driving the flange to `target` (3,) with the rod kept vertical.

    Uses the kinematics stored in `d` (like the MJX law, which reads the data a step left behind)."""
    p, z = flange_pose(d, ids)
    jacp = np.zeros((3, m.nv))
    jacr = np.zeros((3, m.nv))
    mujoco.mj_jac(m, d, jacp, jacr, p, ids.link7_body)
    return law(p, z, jacp[:, :6], jacr[:, :6], d.qpos[:7], target, cfg)


def rod_tilt(z_axis: np.ndarray) -> float:
    """Angle (rad) between the rod and the table normal."""
    return math.acos(min(1.0, max(-1.0, float(C_AXIS @ z_axis))))

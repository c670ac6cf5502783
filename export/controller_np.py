"""The task-space velocity controller on CPU MuJoCo (`mujoco.MjData`): `mjx_push.control_law.law`, the
law the MJX environment runs (`mjx_push.controller`), with NumPy in float64, fed with C MuJoCo's
kinematics (`mujoco.mj_jac`). Only the reading of MjData is this module's own; the law and the tilt are
re-exported under their usual names here. A real robot adapter runs the very same `law` at 1 kHz with its
own kinematics (`export/panda_py_robot.py`, docs/deploy.md).
"""

from __future__ import annotations

import mujoco
import numpy as np

from mjx_push import scene
from mjx_push.config import ControllerConfig
from mjx_push.control_law import C_AXIS, law, rod_tilt  # noqa: F401  (re-exported: the NumPy law)


def flange_pose(d: mujoco.MjData, ids: scene.SceneIds) -> tuple[np.ndarray, np.ndarray]:
    """Flange position (3,) and z axis (3,) from the data's kinematics (copies)."""
    return d.site_xpos[ids.flange_site].copy(), d.site_xmat[ids.flange_site].reshape(3, 3)[:, 2].copy()


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

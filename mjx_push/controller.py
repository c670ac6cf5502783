"""The task-space velocity controller on MJX data, jit-compiled: `mjx_push.control_law` (the law, written
once for NumPy and JAX; docs/task.md section 3) fed with MJX's kinematics.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from mjx_push import control_law, scene
from mjx_push.config import ControllerConfig
from mjx_push.control_law import C_AXIS  # noqa: F401  (re-exported)


def flange_pose(d: mjx.Data, ids: scene.SceneIds) -> tuple[jax.Array, jax.Array]:
    """Flange position (3,) and z axis (3,) from the data's kinematics."""
    return d.site_xpos[ids.flange_site], d.site_xmat[ids.flange_site][:, 2]


def joint_velocity(
    m: mjx.Model, d: mjx.Data, target: jax.Array, ids: scene.SceneIds, cfg: ControllerConfig
) -> jax.Array:
    """Desired joint velocities (7,) driving the flange to `target` (3,) with the rod kept vertical."""
    p, z = flange_pose(d, ids)
    jacp, jacr = mjx.jac(m, d, p, ids.link7_body)  # (nv, 3) each
    return control_law.law(p, z, jacp[:6].T, jacr[:6].T, d.qpos[:7], target, cfg, xp=jnp)


def spd_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """x with a x = b for a small symmetric positive definite `a` (n, n) (n fixed at trace time), by a
    Cholesky factorisation unrolled into scalar arithmetic. On a GPU a general `jnp.linalg.solve`
    becomes a solver library call of its own every substep; these few dozen multiply-adds fuse with the
    rest of the controller. The damped Gram matrix J J^T + lambda^2 I is positive definite for any
    lambda > 0, so the square roots are of positive numbers."""
    n = a.shape[0]
    low = [[None] * n for _ in range(n)]
    for j in range(n):
        low[j][j] = jnp.sqrt(a[j, j] - sum(low[j][k] ** 2 for k in range(j)))
        for i in range(j + 1, n):
            low[i][j] = (a[i, j] - sum(low[i][k] * low[j][k] for k in range(j))) / low[j][j]
    y = []
    for i in range(n):  # L y = b
        y.append((b[i] - sum(low[i][k] * y[k] for k in range(i))) / low[i][i])
    x = [None] * n
    for i in reversed(range(n)):  # L^T x = y
        x[i] = (y[i] - sum(low[k][i] * x[k] for k in range(i + 1, n))) / low[i][i]
    return jnp.stack(x)


def rod_tilt(z_axis: jax.Array) -> jax.Array:
    """Angle (rad) between the rod and the table normal."""
    return control_law.rod_tilt(z_axis, xp=jnp)

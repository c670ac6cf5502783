"""Task-space velocity controller (docs/task.md section 3): the real robot's law, jit-compiled.

Task error e = [c . z_ee - 1 ; p_d - p_ee] with c = (0, 0, -1): the first row keeps the push rod
perpendicular to the table, the other three drive the flange to p_d. Jacobian rows c^T [z_ee]x J_rot and
J_pos over joints 1-6 (joint 7 spins the rod about its own axis and is left still). With that sign
convention J dq = e asks d(c . z_ee)/dt = 1 - c . z_ee, so both rows converge.

That scalar tilt row ("dot", the paper's and the real robot's law) has a vanishing gradient at the
upright pose: its restoring rate grows with the cube of the tilt angle, and in simulation long moves let
the rod drift to 6 degrees (docs/task.md section 8 asks for 2). The default "axis" law therefore replaces it by
two rows linear in the angle: the horizontal components of the angular velocity are asked to equal
(z_ee x c)_xy, the axis-angle that turns z_ee onto c. Select "dot" to reproduce the reference exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from mjx_push import scene
from mjx_push.errors import ConfigError

# A NumPy constant: a jnp array here would start JAX's backend on import, before an entry point could
# choose the CPU device count (mjx_push.xla.use_cpu_devices).
C_AXIS = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class ControllerConfig:
    damping: float = 0.2  # lambda of the damped pseudo-inverse J^T (J J^T + lambda^2 I)^-1
    gain: float = 1.0  # dq = gain * J^+ e (1.0 is the paper's law)
    safety_scale: float = 1.0  # final scale on dq, as on the real robot
    hold_per_step: bool = False  # the reference simulator's variant: dq computed once per env step
    tilt_law: str = "axis"  # "axis" (linear in the tilt angle) or "dot" (the paper's c . z - 1 row)
    tilt_weight: float = 1.0  # "axis" only: weight of the tilt rows against the position rows
    # Extra gain on the rows that hold the rod vertical and the flange at home height (the xy rows keep
    # the paper's unit gain, so actions mean the same). With 1.0 the damped least squares lets z sag by
    # 1-2 cm while the arm reaches out at 0.1 m/s; 10.0 keeps it within 5 mm.
    hold_gain: float = 10.0

    def __post_init__(self):
        if not self.damping > 0:
            raise ConfigError(f"controller.damping must be > 0, got {self.damping}")
        if not self.gain > 0:
            raise ConfigError(f"controller.gain must be > 0, got {self.gain}")
        if self.tilt_law not in ("axis", "dot"):
            raise ConfigError(f"controller.tilt_law must be 'axis' or 'dot', got {self.tilt_law!r}")
        if not self.hold_gain > 0:
            raise ConfigError(f"controller.hold_gain must be > 0, got {self.hold_gain}")
        if not self.tilt_weight > 0:
            raise ConfigError(f"controller.tilt_weight must be > 0, got {self.tilt_weight}")
        if not 0 < self.safety_scale <= 1:
            raise ConfigError(f"controller.safety_scale must be in (0, 1], got {self.safety_scale}")


def flange_pose(d: mjx.Data, ids: scene.SceneIds) -> tuple[jax.Array, jax.Array]:
    """Flange position (3,) and z axis (3,) from the data's kinematics."""
    return d.site_xpos[ids.flange_site], d.site_xmat[ids.flange_site][:, 2]


def joint_velocity(
    m: mjx.Model, d: mjx.Data, target: jax.Array, ids: scene.SceneIds, cfg: ControllerConfig
) -> jax.Array:
    """Desired joint velocities (7,) driving the flange to `target` (3,) with the rod kept vertical."""
    p, z = flange_pose(d, ids)
    jacp, jacr = mjx.jac(m, d, p, ids.link7_body)  # (nv, 3) each
    j_pos = jacp[:6].T
    if cfg.tilt_law == "dot":
        j_tilt = (jnp.cross(C_AXIS, z) @ jacr[:6].T)[None]  # c^T [z]x J_rot
        e_tilt = jnp.dot(C_AXIS, z)[None] - 1.0
    else:
        j_tilt = cfg.tilt_weight * jacr[:6].T[:2]  # world x, y angular velocity
        e_tilt = cfg.tilt_weight * jnp.cross(z, C_AXIS)[:2]
    jac = jnp.concatenate([j_tilt, j_pos], axis=0)  # (4 or 5, 6)
    e_pos = (target - p) * jnp.array([1.0, 1.0, cfg.hold_gain])
    err = jnp.concatenate([cfg.hold_gain * e_tilt, e_pos])
    gram = jac @ jac.T + cfg.damping**2 * jnp.eye(jac.shape[0])
    # spd_solve (below) would fuse on a GPU, but its different rounding flips a borderline corrections
    # count in tests/test_eval.py's scripted pushes; kept off until that test is made robust.
    dq = cfg.gain * (jac.T @ jnp.linalg.solve(gram, err))
    dq = jnp.concatenate([dq, jnp.zeros(1)])
    # Clip to the velocity limits and to the distance left to each position limit (reached no sooner
    # than in 1 s at the law's unit gain); a joint outside its range may only move back in.
    q = d.qpos[:7]
    vlim = jnp.asarray(scene.VELOCITY_LIMIT)
    lo = jnp.maximum(-vlim, jnp.asarray(scene.JOINT_RANGE[:, 0]) - q)
    hi = jnp.minimum(vlim, jnp.asarray(scene.JOINT_RANGE[:, 1]) - q)
    dq = jnp.minimum(jnp.maximum(dq, lo), hi)
    return dq * cfg.safety_scale


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
    return jnp.arccos(jnp.clip(jnp.dot(C_AXIS, z_axis), -1.0, 1.0))

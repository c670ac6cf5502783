"""Binary object masks from the under-table camera, computed analytically (docs/task.md section 2), written
once over an array module `xp` (NumPy, the default, or jax.numpy).

Pixel convention (the same as `mujoco.Renderer.render()` from the camera "under_table"): row 0 is the
top of the image, column 0 the left; columns grow with world +x and rows with world +y (the camera
looks up, so the image is mirrored relative to a top view). Pixel (i, j) is set when its centre
(i + 0.5, j + 0.5) lies inside the silhouette, which is OpenGL's rasterisation rule without
multisampling; the scene disables offscreen multisampling so renders follow the same rule.

Silhouette of an upright prism seen from below: the convex hull of the projections of its bottom face
K (depth d from the camera) and top face. Both faces are parallel to the image plane, so the top face
projects to s*K with s = d / (d + h), a homothety about the principal point; the hull of K and s*K is the
union of t*K over t in [s, 1]. A pixel q is inside iff some t in [s, 1] has q / t in K, which for a
polygon is a set of constraints linear in t and for a disc a quadratic in t: both exact and branch-free.
The object is assumed upright (tilt is ignored; it stays below a degree in normal pushing).

Every function broadcasts over leading batch dimensions of its pose arguments (a stack of poses costs one
NumPy call; JAX callers `vmap` single poses) and computes in the default float type of `xp`: float64 with
NumPy (the CPU environment, `mjx_push.export.cpu_env`), float32 with JAX (the MJX environment through
`mjx_push.masks`, jit-compiled). Pixels whose centre lies within ~1e-6 pixel of the silhouette's edge may
therefore differ between the two (measured agreement in tests/test_cpu_env.py).
This module imports no JAX (`tests/test_deploy_imports.py`).
"""

from __future__ import annotations

import math

import numpy as np

from mjx_push import scene
from mjx_push.errors import ConfigError

IMAGE_SIZE = scene.IMAGE_SIZE
FOCAL = (IMAGE_SIZE / 2) / math.tan(math.radians(scene.CAMERA_FOVY) / 2)  # pixels
_CAM_XY = np.asarray(scene.CAMERA_POS[:2], dtype=np.float64)
_CAM_Z = float(scene.CAMERA_POS[2])


def _pixel_offsets(n: int = IMAGE_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres relative to the principal point: (cols, rows), each (n, n), = world (x, y) direction."""
    c = np.arange(n, dtype=np.float64) + 0.5 - n / 2
    cols, rows = np.meshgrid(c, c, indexing="xy")
    return cols, rows


# Half-integers: exact in any float type, so computing them once in float64 loses nothing.
_QX, _QY = _pixel_offsets()


def _lift(a):
    """Lift a batch of scalars (...) to (..., 1, 1) so it broadcasts against the pixel grid."""
    return a[..., None, None]


def _projection(center_xy, z_bottom, height, xp):
    """Principal-point offset q0 (..., 2) of the bottom face's centre, 1 / depth scale and s = d / (d + h)."""
    d = xp.asarray(z_bottom, dtype=float) - _CAM_Z
    s = d / (d + xp.asarray(height, dtype=float))
    q0 = FOCAL * (xp.asarray(center_xy, dtype=float) - xp.asarray(_CAM_XY)) / d[..., None]
    return q0, d, s


def box_mask(center_xy, yaw, half_sides, z_bottom, height, *, xp=np):
    """Masks (..., 64, 64) bool of boxes with half extents `half_sides` (..., 2), bottom face at `z_bottom`."""
    q0, d, s = _projection(center_xy, z_bottom, height, xp)
    half_sides = xp.asarray(half_sides, dtype=float)
    yaw = xp.asarray(yaw, dtype=float)
    a = FOCAL * half_sides[..., 0] / d
    b = FOCAL * half_sides[..., 1] / d
    cos, sin = xp.cos(yaw), xp.sin(yaw)
    qx, qy = xp.asarray(_QX, dtype=float), xp.asarray(_QY, dtype=float)
    # Pixel coordinates along the box's own axes u1 = (cos, sin), u2 = (-sin, cos).
    p1 = qx * _lift(cos) + qy * _lift(sin)
    p2 = -qx * _lift(sin) + qy * _lift(cos)
    c1 = q0[..., 0] * cos + q0[..., 1] * sin
    c2 = -q0[..., 0] * sin + q0[..., 1] * cos
    # The pixel q is inside the face scaled by t iff p_k - t r_k <= 0 for the four sides k.
    p = xp.stack([p1, -p1, p2, -p2], axis=-1)
    r = xp.stack([c1 + a, a - c1, c2 + b, b - c2], axis=-1)[..., None, None, :]
    return _linear_feasible(p, r, _lift(s), xp)


def _linear_feasible(p, r, s, xp):
    """Is there t in [s, 1] with p_k - t r_k <= 0 for all k? p (..., K), r broadcastable to p."""
    big = 1e9
    safe_r = xp.where(r == 0, 1.0, r)
    ratio = p / safe_r
    lo = xp.max(xp.where(r > 0, ratio, -big), axis=-1)
    hi = xp.min(xp.where(r < 0, ratio, big), axis=-1)
    zero_ok = xp.all(xp.where(r == 0, p <= 0, True), axis=-1)
    return (xp.maximum(lo, s) <= xp.minimum(hi, 1.0)) & zero_ok


def cylinder_mask(center_xy, radius, z_bottom, height, *, xp=np):
    """Masks (..., 64, 64) bool of upright cylinders whose bottom face is at `z_bottom`."""
    q0, d, s = _projection(center_xy, z_bottom, height, xp)
    rho = FOCAL * xp.asarray(radius, dtype=float) / d
    qx, qy = xp.asarray(_QX, dtype=float), xp.asarray(_QY, dtype=float)
    # |q - t q0|^2 - t^2 rho^2 = A t^2 - 2 B t + C <= 0 for some t in [s, 1]: the minimum over the
    # interval is at an end or, when A > 0 (convex), at the clipped vertex B / A.
    A = _lift(xp.sum(q0 * q0, axis=-1) - rho**2)
    B = qx * _lift(q0[..., 0]) + qy * _lift(q0[..., 1])
    C = qx**2 + qy**2
    s = _lift(s)

    def h(t):
        return A * t**2 - 2 * B * t + C

    with np.errstate(divide="ignore", invalid="ignore"):  # NumPy only; nothing to JAX
        t_star = xp.clip(B / xp.where(A > 0, A, 1.0), s, 1.0)
    h_star = xp.where(A > 0, h(t_star), xp.inf)
    return xp.minimum(xp.minimum(h(s), h(1.0)), h_star) <= 0


def object_mask(geom_type: str, size, xy, yaw, z_center, *, xp=np):
    """Mask(s) of objects with MJCF geom size `size` (..., 3) at (xy (..., 2), yaw (...)) and centre
    height `z_center` (...). Returns bool (..., 64, 64)."""
    size = xp.asarray(size, dtype=float)
    z_center = xp.asarray(z_center, dtype=float)
    if geom_type == "box":
        half_h = size[..., 2]
        return box_mask(xy, yaw, size[..., :2], z_center - half_h, 2 * half_h, xp=xp)
    if geom_type == "cylinder":
        half_h = size[..., 1]
        return cylinder_mask(xy, size[..., 0], z_center - half_h, 2 * half_h, xp=xp)
    raise ConfigError(f"geom_type must be one of {scene.SHAPES}, got {geom_type!r}")

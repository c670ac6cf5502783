"""NumPy port of `mjx_push.masks`: analytic object masks without JAX or a renderer.

Same geometry and pixel convention as the JAX version (row 0 is the top of `mujoco.Renderer.render()`
from camera "under_table", columns grow with world +x, rows with world +y; a pixel is set when its centre
lies inside the silhouette, the convex hull of the projected bottom and top faces). Every function
broadcasts over leading batch dimensions of its pose arguments, so a stack of poses costs one call.
The JAX version computes in float32, this one in float64: pixels whose centre lies within ~1e-6 pixel of
the silhouette's edge may differ (measured agreement in tests/test_cpu_env.py).
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


_QX, _QY = _pixel_offsets()


def _e(a: np.ndarray) -> np.ndarray:
    """Lift a batch of scalars (...) to (..., 1, 1) so it broadcasts against the pixel grid."""
    return np.asarray(a, dtype=np.float64)[..., None, None]


def box_mask(center_xy, yaw, half_sides, z_bottom, height) -> np.ndarray:
    """Masks (..., 64, 64) bool of boxes with half extents `half_sides` (..., 2), bottom face at `z_bottom`."""
    center_xy = np.asarray(center_xy, np.float64)
    half_sides = np.asarray(half_sides, np.float64)
    yaw = np.asarray(yaw, np.float64)
    d = np.asarray(z_bottom, np.float64) - _CAM_Z
    s = d / (d + np.asarray(height, np.float64))
    q0 = FOCAL * (center_xy - _CAM_XY) / d[..., None]
    a = FOCAL * half_sides[..., 0] / d
    b = FOCAL * half_sides[..., 1] / d
    cos, sin = np.cos(yaw), np.sin(yaw)
    # Pixel coordinates along the box's own axes u1 = (cos, sin), u2 = (-sin, cos).
    p1 = _QX * _e(cos) + _QY * _e(sin)
    p2 = -_QX * _e(sin) + _QY * _e(cos)
    c1 = q0[..., 0] * cos + q0[..., 1] * sin
    c2 = -q0[..., 0] * sin + q0[..., 1] * cos
    # The pixel q is inside the face scaled by t iff p_k - t r_k <= 0 for the four sides k.
    p = np.stack([p1, -p1, p2, -p2], axis=-1)
    r = np.stack([c1 + a, a - c1, c2 + b, b - c2], axis=-1)[..., None, None, :]
    return _linear_feasible(p, r, _e(s))


def _linear_feasible(p: np.ndarray, r: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Is there t in [s, 1] with p_k - t r_k <= 0 for all k? p (..., K), r broadcastable to p."""
    big = 1e9
    safe_r = np.where(r == 0, 1.0, r)
    ratio = p / safe_r
    lo = np.max(np.where(r > 0, ratio, -big), axis=-1)
    hi = np.min(np.where(r < 0, ratio, big), axis=-1)
    zero_ok = np.all(np.where(r == 0, p <= 0, True), axis=-1)
    return (np.maximum(lo, s) <= np.minimum(hi, 1.0)) & zero_ok


def cylinder_mask(center_xy, radius, z_bottom, height) -> np.ndarray:
    """Masks (..., 64, 64) bool of upright cylinders whose bottom face is at `z_bottom`."""
    center_xy = np.asarray(center_xy, np.float64)
    d = np.asarray(z_bottom, np.float64) - _CAM_Z
    s = d / (d + np.asarray(height, np.float64))
    q0 = FOCAL * (center_xy - _CAM_XY) / d[..., None]
    rho = FOCAL * np.asarray(radius, np.float64) / d
    # |q - t q0|^2 - t^2 rho^2 = A t^2 - 2 B t + C <= 0 for some t in [s, 1]: the minimum over the
    # interval is at an end or, when A > 0 (convex), at the clipped vertex B / A.
    A = _e(np.sum(q0 * q0, axis=-1) - rho**2)
    B = _QX * _e(q0[..., 0]) + _QY * _e(q0[..., 1])
    C = _QX**2 + _QY**2
    s = _e(s)

    def h(t):
        return A * t**2 - 2 * B * t + C

    with np.errstate(divide="ignore", invalid="ignore"):
        t_star = np.clip(B / np.where(A > 0, A, 1.0), s, 1.0)
    h_star = np.where(A > 0, h(t_star), np.inf)
    return np.minimum(np.minimum(h(s), h(1.0)), h_star) <= 0


def object_mask(geom_type: str, size, xy, yaw, z_center) -> np.ndarray:
    """Mask(s) of objects with MJCF geom size `size` (..., 3) at (xy (..., 2), yaw (...)) and centre
    height `z_center` (...). Returns bool (..., 64, 64)."""
    size = np.asarray(size, np.float64)
    z_center = np.asarray(z_center, np.float64)
    if geom_type == "box":
        half_h = size[..., 2]
        return box_mask(xy, yaw, size[..., :2], z_center - half_h, 2 * half_h)
    if geom_type == "cylinder":
        half_h = size[..., 1]
        return cylinder_mask(xy, size[..., 0], z_center - half_h, 2 * half_h)
    raise ConfigError(f"geom_type must be one of {scene.SHAPES}, got {geom_type!r}")

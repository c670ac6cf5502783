"""Binary object masks from the under-table camera, computed analytically on device (docs/task.md section 2).

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
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from mjx_push import scene
from mjx_push.errors import ConfigError

FOCAL = (scene.IMAGE_SIZE / 2) / math.tan(math.radians(scene.CAMERA_FOVY) / 2)  # pixels


def _pixel_offsets(n: int = scene.IMAGE_SIZE) -> jax.Array:
    """(n, n, 2) pixel centres relative to the principal point, as (col, row) = world (x, y) direction."""
    c = jnp.arange(n, dtype=jnp.result_type(float)) + 0.5 - n / 2
    cols, rows = jnp.meshgrid(c, c, indexing="xy")
    return jnp.stack([cols, rows], axis=-1)


def _bottom_depth(z_bottom):
    return z_bottom - scene.CAMERA_POS[2]


def box_mask(center_xy, yaw, half_sides, z_bottom, height) -> jax.Array:
    """Mask (64, 64) bool of a box with half extents `half_sides` (2,) whose bottom face is at `z_bottom`."""
    d = _bottom_depth(z_bottom)
    s = d / (d + height)
    q0 = FOCAL * (center_xy - jnp.asarray(scene.CAMERA_POS[:2])) / d
    a, b = FOCAL * half_sides[0] / d, FOCAL * half_sides[1] / d
    u1 = jnp.stack([jnp.cos(yaw), jnp.sin(yaw)])
    u2 = jnp.stack([-jnp.sin(yaw), jnp.cos(yaw)])
    q = _pixel_offsets()
    p1, p2 = q @ u1, q @ u2
    c1, c2 = q0 @ u1, q0 @ u2
    # Constraints p_k - t r_k <= 0 for the four sides of K scaled by t.
    p = jnp.stack([p1, -p1, p2, -p2], axis=-1)
    r = jnp.stack([c1 + a, a - c1, c2 + b, b - c2])
    return _linear_feasible(p, r, s)


def _linear_feasible(p, r, s):
    """Is there t in [s, 1] with p_k - t r_k <= 0 for all k? p (..., K), r (K,)."""
    big = 1e9
    safe_r = jnp.where(r == 0, 1.0, r)
    ratio = p / safe_r
    lo = jnp.max(jnp.where(r > 0, ratio, -big), axis=-1)
    hi = jnp.min(jnp.where(r < 0, ratio, big), axis=-1)
    zero_ok = jnp.all(jnp.where(r == 0, p <= 0, True), axis=-1)
    return (jnp.maximum(lo, s) <= jnp.minimum(hi, 1.0)) & zero_ok


def cylinder_mask(center_xy, radius, z_bottom, height) -> jax.Array:
    """Mask (64, 64) bool of an upright cylinder whose bottom face is at `z_bottom`."""
    d = _bottom_depth(z_bottom)
    s = d / (d + height)
    q0 = FOCAL * (center_xy - jnp.asarray(scene.CAMERA_POS[:2])) / d
    rho = FOCAL * radius / d
    q = _pixel_offsets()
    # |q - t q0|^2 - t^2 rho^2 = A t^2 - 2 B t + C <= 0 for some t in [s, 1]; the minimum over the
    # interval is at an end or, when A > 0 (convex), at the clipped vertex B / A.
    A = q0 @ q0 - rho**2
    B = q @ q0
    C = jnp.sum(q * q, axis=-1)

    def h(t):
        return A * t**2 - 2 * B * t + C

    t_star = jnp.clip(B / jnp.where(A > 0, A, 1.0), s, 1.0)
    h_star = jnp.where(A > 0, h(t_star), jnp.inf)
    return jnp.minimum(jnp.minimum(h(s), h(1.0)), h_star) <= 0


def object_mask(geom_type: str, size, xy, yaw, z_center) -> jax.Array:
    """Mask of the object with MJCF geom size `size` (3,) at (xy, yaw), centre height `z_center`."""
    if geom_type == "box":
        half_h = size[2]
        return box_mask(xy, yaw, size[:2], z_center - half_h, 2 * half_h)
    if geom_type == "cylinder":
        half_h = size[1]
        return cylinder_mask(xy, size[0], z_center - half_h, 2 * half_h)
    raise ConfigError(f"geom_type must be one of {scene.SHAPES}, got {geom_type!r}")

"""Binary object masks from the under-table camera on device (docs/task.md section 2): the analytic
masks of `mjx_push.mask_geometry` (written once for NumPy and JAX; the pixel convention and the
geometry are documented there) evaluated with jax.numpy, jittable and vmappable, in JAX's default float.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjx_push import mask_geometry
from mjx_push.mask_geometry import FOCAL  # noqa: F401  (re-exported)


def box_mask(center_xy, yaw, half_sides, z_bottom, height) -> jax.Array:
    """Mask (64, 64) bool of a box with half extents `half_sides` (2,) whose bottom face is at `z_bottom`."""
    return mask_geometry.box_mask(center_xy, yaw, half_sides, z_bottom, height, xp=jnp)


def cylinder_mask(center_xy, radius, z_bottom, height) -> jax.Array:
    """Mask (64, 64) bool of an upright cylinder whose bottom face is at `z_bottom`."""
    return mask_geometry.cylinder_mask(center_xy, radius, z_bottom, height, xp=jnp)


def object_mask(geom_type: str, size, xy, yaw, z_center) -> jax.Array:
    """Mask of the object with MJCF geom size `size` (3,) at (xy, yaw), centre height `z_center`."""
    return mask_geometry.object_mask(geom_type, size, xy, yaw, z_center, xp=jnp)

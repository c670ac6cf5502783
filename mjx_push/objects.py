"""Per-environment object randomisation (docs/task.md sections 1 and 4) and its application to an MJX model.

Shape is the one parameter MJX cannot vary per environment (a geom's type is static), so every
`PushEnv` is specialised to one geom type ("box" or "cylinder") and `mjx_push.batch` splits a batch
between the two. Within a type everything else (sizes, height, mass, inertia, friction, poses) is drawn
here per environment, and `apply` writes it into that environment's copy of the model.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjx_push import scene, task_rules
from mjx_push.config import (  # noqa: F401  (the JAX-free definitions, under their usual names here)
    MODES,
    OBJECT_PARAM_FIELDS,
    RECT_MIN_DIFF,
    SHAPE_FILTERS,
    ObjectConfig,
    ObjectParams,
    ShapeFilter,
    half_height,
)
from mjx_push.errors import ConfigError

# ObjectParams is defined without JAX (mjx_push.config); it becomes a pytree here, with its fields as
# children and the key paths of the `flax.struct.dataclass` it used to be.
jax.tree_util.register_dataclass(ObjectParams, data_fields=list(OBJECT_PARAM_FIELDS), meta_fields=[])


def sample_improved_mass(key: jax.Array, cfg: ObjectConfig, shape=()) -> jax.Array:
    """m = ((F_max - F_min)/mu_k) * ((1-x)(1-y) + x y) + F_min/mu_k, x ~ Exp(scale) clipped to [0, 1],
    y ~ Bernoulli(0.5) (paper eq. 3, docs/task.md section 4)."""
    kx, ky = jax.random.split(key)
    f_min = cfg.mass[0] * cfg.friction[0]
    f_max = cfg.mass[1] * cfg.friction[1]
    x = jnp.clip(jax.random.exponential(kx, shape) * cfg.exp_scale, 0.0, 1.0)
    y = jax.random.bernoulli(ky, 0.5, shape).astype(jnp.result_type(float))
    return (f_max - f_min) / cfg.mu_k * ((1 - x) * (1 - y) + x * y) + f_min / cfg.mu_k


def _uniform(key, r):
    return jax.random.uniform(key, (), minval=r[0], maxval=r[1])


def _box_sides(key, cfg: ObjectConfig):
    k1, k2 = jax.random.split(key)
    lo, hi = cfg.side
    length = _uniform(k1, cfg.side)
    if cfg.shape == "square":
        width = length
    elif cfg.shape == "rectangular":
        # Uniform over [lo, hi] minus (length - d, length + d): draw a point in the total allowed
        # measure and map it onto the two pieces.
        a = jnp.maximum(length - RECT_MIN_DIFF - lo, 0.0)
        b = jnp.maximum(hi - length - RECT_MIN_DIFF, 0.0)
        u = jax.random.uniform(k2, ()) * (a + b)
        width = jnp.where(u < a, lo + u, length + RECT_MIN_DIFF + (u - a))
    else:
        width = _uniform(k2, cfg.side)
    return length, width


def _pose(key, home_xy, cfg: ObjectConfig, min_dist: float):
    # Rejection sampling without a loop: draw candidates, keep the first far enough from home.
    # P(all 64 fail) < 1e-6 at the defaults; if it happens the last candidate is pushed out radially.
    kxy, kyaw = jax.random.split(key)
    r = cfg.pose_range
    cand = jax.random.uniform(kxy, (64, 2), minval=-r, maxval=r)
    ok = jnp.linalg.norm(cand, axis=-1) >= min_dist
    first = jnp.argmax(ok)
    off = jnp.where(ok.any(), cand[first], cand[-1] / jnp.maximum(jnp.linalg.norm(cand[-1]), 1e-9) * min_dist)
    yaw = jax.random.uniform(kyaw, (), minval=-jnp.pi, maxval=jnp.pi)
    return jnp.concatenate([home_xy + off, yaw[None]])


def sample(key: jax.Array, cfg: ObjectConfig, geom_type: str, home_xy: jax.Array) -> ObjectParams:
    """Draw one environment's object of `geom_type` ("box" or "cylinder") under `cfg`."""
    if geom_type not in cfg.shapes():
        raise ConfigError(f"shape filter {cfg.shape!r} draws no {geom_type!r}")
    ks = jax.random.split(key, 7)
    if geom_type == "box":
        length, width = _box_sides(ks[0], cfg)
        h_max = jnp.minimum(jnp.minimum(cfg.max_height_cuboid, length), width)
    else:
        radius = _uniform(ks[0], cfg.radius)
        h_max = jnp.asarray(cfg.max_height_cylinder)
    # If the shape caps the height below min_height (e.g. the difficult case), min_height wins.
    height = cfg.min_height + jax.random.uniform(ks[1], ()) * jnp.maximum(h_max - cfg.min_height, 0.0)
    if cfg.mode == "uniform":
        mass = _uniform(ks[2], cfg.mass)
        mu = _uniform(ks[3], cfg.friction)
    else:
        mass = sample_improved_mass(ks[2], cfg)
        mu = jnp.asarray(cfg.mu_k, jnp.result_type(float))
    torsional = _uniform(ks[4], cfg.torsional)
    if geom_type == "box":
        size = jnp.stack([length / 2, width / 2, height / 2])
        inertia = mass / 12.0 * jnp.stack([width**2 + height**2, length**2 + height**2, length**2 + width**2])
    else:
        size = jnp.stack([radius, height / 2, 0.0])
        ixx = mass * (3 * radius**2 + height**2) / 12.0
        inertia = jnp.stack([ixx, ixx, mass * radius**2 / 2])
    friction = jnp.stack([mu, torsional, jnp.asarray(scene.OBJECT_ROLL_FRICTION, jnp.result_type(float))])
    start = _pose(ks[5], home_xy, cfg, cfg.min_start_dist)
    goal = _pose(ks[6], home_xy, cfg, 0.0)
    return ObjectParams(size=size, mass=mass, inertia=inertia, friction=friction, start=start, goal=goal)


def apply(model, params: ObjectParams, ids: scene.SceneIds, geom_type: str):
    """This environment's model: the object's size, mass, inertia, friction and the quantities MuJoCo
    derives from them (bounding radius, inverse weights used by the constraint solver's regularisation)."""
    g, b, v = ids.object_geom, ids.object_body, ids.object_qvel
    rbound, aabb_half = task_rules.object_bounds(params.size, geom_type, xp=jnp)
    inv_rot = jnp.mean(1.0 / params.inertia)
    inv_w = jnp.stack([1.0 / params.mass, inv_rot])
    dof_inv = jnp.concatenate([jnp.full(3, 1.0 / params.mass), jnp.full(3, inv_rot)])
    return model.tree_replace(
        {
            "geom_size": model.geom_size.at[g].set(params.size),
            "geom_rbound": model.geom_rbound.at[g].set(rbound),
            "geom_aabb": model.geom_aabb.at[g, 3:].set(aabb_half),
            "geom_friction": model.geom_friction.at[g].set(params.friction),
            "body_mass": model.body_mass.at[b].set(params.mass),
            "body_inertia": model.body_inertia.at[b].set(params.inertia),
            "body_invweight0": model.body_invweight0.at[b].set(inv_w),
            "dof_invweight0": model.dof_invweight0.at[v : v + 6].set(dof_inv),
        }
    )

"""Per-environment object randomisation (docs/task.md sections 1 and 4) and its application to an MJX model.

Shape is the one parameter MJX cannot vary per environment (a geom's type is static), so every
`PushEnv` is specialised to one geom type ("box" or "cylinder") and `mjx_push.batch` splits a batch
between the two. Within a type everything else (sizes, height, mass, inertia, friction, poses) is drawn
here per environment, and `apply` writes it into that environment's copy of the model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import jax
import jax.numpy as jnp
from flax import struct

from mjx_push import scene
from mjx_push.errors import ConfigError

ShapeFilter = Literal["any", "cylinder", "cuboid", "square", "rectangular"]
SHAPE_FILTERS = ("any", "cylinder", "cuboid", "square", "rectangular")
MODES = ("uniform", "improved")
RECT_MIN_DIFF = 0.02  # "rectangular": length and width differ by at least this


def _check_range(name: str, r, lo_bound: float = 0.0):
    if len(r) != 2:
        raise ConfigError(f"objects.{name} must be a (low, high) pair, got {r!r}")
    lo, hi = float(r[0]), float(r[1])
    if not (lo == lo and hi == hi) or lo > hi or lo < lo_bound:
        raise ConfigError(f"objects.{name} must satisfy {lo_bound} <= low <= high, got {r!r}")


@dataclass(frozen=True)
class ObjectConfig:
    """Object distribution: Table I of the paper by default. Every range is (low, high), full sizes."""

    mode: Literal["uniform", "improved"] = "uniform"
    shape: ShapeFilter = "any"
    radius: tuple[float, float] = (0.04, 0.055)
    side: tuple[float, float] = (0.05, 0.11)  # cuboid length and width, each
    min_height: float = 0.046
    max_height_cuboid: float = 0.08  # further capped by the cuboid's length and width
    max_height_cylinder: float = 0.055
    mass: tuple[float, float] = (0.001, 1.0)
    friction: tuple[float, float] = (0.2, 1.0)
    torsional: tuple[float, float] = (0.001, 0.01)
    mu_k: float = 0.4  # improved mode: fixed sliding friction coefficient
    exp_scale: float = 1.0 / 7.0  # improved mode: scale of the exponential
    pose_range: float = 0.1  # start and goal: EE_home_xy + U[-r, r]^2
    min_start_dist: float = 0.1  # start at least this far from EE_home_xy

    def __post_init__(self):
        if self.mode not in MODES:
            raise ConfigError(f"objects.mode must be one of {MODES}, got {self.mode!r}")
        if self.shape not in SHAPE_FILTERS:
            raise ConfigError(f"objects.shape must be one of {SHAPE_FILTERS}, got {self.shape!r}")
        _check_range("radius", self.radius, 1e-3)
        _check_range("side", self.side, 1e-3)
        _check_range("mass", self.mass, 1e-5)
        _check_range("friction", self.friction, scene.MIN_OBJECT_FRICTION)
        _check_range("torsional", self.torsional, scene.TABLE_FRICTION[1])
        if not 0.005 <= self.min_height <= 0.2:
            raise ConfigError(f"objects.min_height must be in [0.005, 0.2], got {self.min_height}")
        for name in ("max_height_cuboid", "max_height_cylinder"):
            if getattr(self, name) < self.min_height:
                raise ConfigError(f"objects.{name} must be >= objects.min_height, got {getattr(self, name)}")
        if self.radius[1] > 0.08 or self.side[1] > 0.16:
            raise ConfigError("objects.radius high must be <= 0.08 and objects.side high <= 0.16 (scene limits)")
        if self.shape == "rectangular" and self.side[1] - self.side[0] < RECT_MIN_DIFF:
            raise ConfigError(
                f"objects.side must span at least {RECT_MIN_DIFF} for shape 'rectangular', got {self.side}"
            )
        if self.mu_k <= 0:
            raise ConfigError(f"objects.mu_k must be > 0, got {self.mu_k}")
        if self.exp_scale <= 0:
            raise ConfigError(f"objects.exp_scale must be > 0, got {self.exp_scale}")
        if not 0 < self.pose_range <= 0.25:
            raise ConfigError(f"objects.pose_range must be in (0, 0.25], got {self.pose_range}")
        if not 0 <= self.min_start_dist < self.pose_range * 2**0.5:
            raise ConfigError(f"objects.min_start_dist must be in [0, pose_range*sqrt(2)), got {self.min_start_dist}")

    def shapes(self) -> tuple[str, ...]:
        """Geom types this filter draws: subset of scene.SHAPES."""
        if self.shape == "any":
            return scene.SHAPES
        return ("cylinder",) if self.shape == "cylinder" else ("box",)


@struct.dataclass
class ObjectParams:
    """One environment's object. `size` is the MJCF geom size (box: half extents; cylinder: radius,
    half height, 0); poses are (x, y, yaw)."""

    size: jax.Array  # (3,)
    mass: jax.Array  # ()
    inertia: jax.Array  # (3,) principal, about the centre of mass
    friction: jax.Array  # (3,) sliding, torsional, rolling
    start: jax.Array  # (3,)
    goal: jax.Array  # (3,)


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


def half_height(params: ObjectParams, geom_type: str) -> jax.Array:
    return params.size[2] if geom_type == "box" else params.size[1]


def apply(model, params: ObjectParams, ids: scene.SceneIds, geom_type: str):
    """This environment's model: the object's size, mass, inertia, friction and the quantities MuJoCo
    derives from them (bounding radius, inverse weights used by the constraint solver's regularisation)."""
    g, b, v = ids.object_geom, ids.object_body, ids.object_qvel
    if geom_type == "box":
        rbound = jnp.linalg.norm(params.size)
        aabb_half = params.size
    else:
        rbound = jnp.sqrt(params.size[0] ** 2 + params.size[1] ** 2)
        aabb_half = jnp.stack([params.size[0], params.size[0], params.size[1]])
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

"""The task's settings and the object record, without JAX: what the MJX environment, the CPU MuJoCo
environment and a robot all read (docs/task.md sections 1, 3 and 4).

- `ObjectConfig`: the object distribution (drawn by `mjx_push.objects.sample`, which needs JAX);
- `ObjectParams`: one drawn object. A frozen dataclass here; `mjx_push.objects` (imported by every JAX
  module of the package) registers it as a JAX pytree with the fields as children, as
  `flax.struct.dataclass` did, so JAX code batches, traces and checkpoints it as before;
- `ControllerConfig`: the task-space velocity law (`mjx_push.control_law`);
- `EnvConfig`: the environment, holding the three above, the MJX solver settings and the perturbations
  of a real cell (`mjx_push.perturb.PerturbConfig`, off by default).

The usual import paths still give these very classes: `mjx_push.env.EnvConfig`,
`mjx_push.objects.ObjectConfig` / `ObjectParams`, `mjx_push.controller.ControllerConfig`.
This module imports no JAX (`tests/test_deploy_imports.py`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from mjx_push import scene
from mjx_push.errors import ConfigError
from mjx_push.perturb import PerturbConfig
from mjx_push.task_rules import TAU

# --- objects ----------------------------------------------------------------------------------------
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


@dataclass(frozen=True)
class ObjectParams:
    """One environment's object. `size` is the MJCF geom size (box: half extents; cylinder: radius,
    half height, 0); poses are (x, y, yaw). Leaves are JAX arrays in the MJX environment, NumPy arrays
    in the CPU one (`mjx_push.export.cpu_env.params_to_numpy`)."""

    size: Any  # (3,)
    mass: Any  # ()
    inertia: Any  # (3,) principal, about the centre of mass
    friction: Any  # (3,) sliding, torsional, rolling
    start: Any  # (3,)
    goal: Any  # (3,)

    def replace(self, **updates) -> ObjectParams:
        """A copy with the given fields replaced (as `flax.struct.dataclass` objects have)."""
        return dataclasses.replace(self, **updates)


OBJECT_PARAM_FIELDS = tuple(f.name for f in dataclasses.fields(ObjectParams))


def half_height(params: ObjectParams, geom_type: str):
    """Half the object's height: the box's third half extent, the cylinder's half length."""
    return params.size[2] if geom_type == "box" else params.size[1]


# --- controller -------------------------------------------------------------------------------------
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


# --- environment ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class EnvConfig:
    """Task settings (docs/task.md section 3). Nested configs hold the object distribution, the controller and
    the MJX solver."""

    objects: ObjectConfig = field(default_factory=ObjectConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    solver: scene.SolverSettings = field(default_factory=scene.SolverSettings)
    action_scale: float = 1.0  # metres per unit of a_x, a_y
    substeps: tuple[int, int] = (10, 600)  # a_s in [-1, 1] maps linearly onto this, truncated
    episode_length: int = 50
    success_tau: float = TAU
    obs_noise: float = 1e-4  # std of the Gaussian noise on the observed flange xy
    workspace_x: tuple[float, float] = (0.10, 0.65)
    workspace_y: tuple[float, float] = (-0.25, 0.25)
    # Out-of-bounds: the object's centre must stay above the table footprint and within this height
    # band around its resting height (below: sank through; above: flew off).
    oob_sink: float = 0.02
    oob_rise: float = 0.15
    # What a real cell brings (camera, latency, controller, object and rod errors): off by default;
    # training-time randomisation when set (mjx_push.perturb, docs/robustness.md).
    perturb: PerturbConfig = field(default_factory=PerturbConfig)

    def __post_init__(self):
        lo, hi = self.substeps
        if not (isinstance(lo, (int, np.integer)) and isinstance(hi, (int, np.integer)) and 1 <= lo <= hi):
            raise ConfigError(f"env.substeps must be integers 1 <= low <= high, got {self.substeps!r}")
        if not self.action_scale > 0:
            raise ConfigError(f"env.action_scale must be > 0, got {self.action_scale}")
        if self.episode_length < 1:
            raise ConfigError(f"env.episode_length must be >= 1, got {self.episode_length}")
        if not self.success_tau > 0:
            raise ConfigError(f"env.success_tau must be > 0, got {self.success_tau}")
        if self.obs_noise < 0:
            raise ConfigError(f"env.obs_noise must be >= 0, got {self.obs_noise}")
        for name in ("workspace_x", "workspace_y"):
            r = getattr(self, name)
            if len(r) != 2 or not r[0] < r[1]:
                raise ConfigError(f"env.{name} must be (low, high) with low < high, got {r!r}")

    def object_in_bounds(self, x, y, z, rest_z):
        """The out-of-bounds rule: the object's centre (x, y, z) lies over the table footprint and within
        (rest_z - oob_sink, rest_z + oob_rise) of its resting height. Operators only, so it evaluates
        NumPy scalars (the CPU environment) and traced JAX arrays (the MJX one) alike."""
        on_table = (x >= scene.TABLE_X[0]) & (x <= scene.TABLE_X[1]) & (y >= scene.TABLE_Y[0]) & (y <= scene.TABLE_Y[1])
        in_band = (z > rest_z - self.oob_sink) & (z < rest_z + self.oob_rise)
        return on_table & in_band

"""What a real robot cell brings and the simulation does not: camera masks with pixel errors, a
camera calibrated to millimetres, the time between image and command, an arm that tracks velocity
imperfectly, objects and a push rod off their nominal values (docs/robustness.md).

`PerturbConfig` (the `env.perturb` section of the task's settings, off by default) says how large each
perturbation is. At reset an environment turns it into one episode's record (`draw_episode`: the
camera's offset, the latency, the controller's gain and lag, the object's mass and friction factors,
the rod's errors, and the per-frame rates), from which every step applies the functions below. They
are written once over an array module `xp` (NumPy, the default, or jax.numpy) and are pure: the MJX
environment (`mjx_push.env`) runs them under `jit`/`vmap`, the CPU MuJoCo one
(`mjx_push.export.cpu_env`) with NumPy.

A record whose values are all neutral (zeros; factors of one) changes nothing, bit for bit: every
function below is written so that its neutral values add an exact zero or multiply by an exact one.
The stress suite (`mjx_push.train.stress`) relies on it: one compiled episode runner serves every
perturbation and level, the clean row included.

Sampling: "fixed" applies each magnitude as stated (a direction or sign drawn per episode where the
field has none: the stress suite's levels); "uniform" draws each from none up to the stated magnitude,
in either direction (training-time randomisation).

This module imports no JAX (`tests/test_deploy_imports.py`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from mjx_push import scene
from mjx_push.errors import ConfigError

SAMPLES = ("fixed", "uniform")
LEVELS = ("mild", "realistic", "severe")
MAX_EDGE = 3  # pixels: the largest erosion or dilation (a static loop bound under jit)
MAX_OPEN_CLOSE = 3  # the largest opening/closing radius

# Each field's neutral value and its accepted range (inclusive).
_RANGES = {
    "mask_flip": (0.0, 0.0, 0.5),
    "mask_edge": (0.0, -MAX_EDGE, MAX_EDGE),
    "mask_open_close": (0, 0, MAX_OPEN_CLOSE),
    "frame_repeat": (0.0, 0.0, 1.0),
    "frame_empty": (0.0, 0.0, 1.0),
    "camera_shift": (0.0, 0.0, 0.05),
    "camera_yaw": (0.0, 0.0, 0.2),
    "latency": (0, 0, 600),
    "flange_noise": (0.0, 0.0, 0.05),
    "velocity_gain": (0.0, 0.0, 0.9),
    "velocity_lag": (0.0, 0.0, 1000.0),
    "mass_factor": (1.0, 1.0, 100.0),
    "friction_factor": (1.0, 1.0, 10.0),
    "rod_radius": (0.0, 0.0, 0.005),
    "rod_length": (0.0, 0.0, 0.02),
}
FIELDS = tuple(_RANGES)


@dataclass(frozen=True)
class PerturbConfig:
    """Magnitudes of the perturbations; every default is neutral (the simulation as it was)."""

    # Masks, per frame, object and goal masks alike (one camera takes both).
    mask_flip: float = 0.0  # probability per pixel that it flips (specks, holes)
    # Pixels of dilation (> 0) or erosion (< 0) of the silhouette's edge; a fractional part is the
    # probability, per frame, of one pixel more (an edge that flickers).
    mask_edge: float = 0.0
    mask_open_close: int = 0  # radius r of an opening then a closing with a (2r+1)^2 square (1: 3 x 3)
    frame_repeat: float = 0.0  # probability per step that the frame is missed and the last mask shown again
    frame_empty: float = 0.0  # probability per step that the frame is missed and an empty mask shown
    # The camera's extrinsics: an xy offset (m) and a rotation about its optical axis (rad). Object and
    # goal masks move alike; the flange reading comes from the arm, not the camera.
    camera_shift: float = 0.0
    camera_yaw: float = 0.0
    latency: int = 0  # substeps (ms) the previous command runs on before a new one takes effect
    flange_noise: float = 0.0  # m: standard deviation of extra noise on the observed flange xy
    velocity_gain: float = 0.0  # the joints run (1 +- this) x the commanded velocity
    velocity_lag: float = 0.0  # ms: time constant of a first-order lag between command and servo
    mass_factor: float = 1.0  # the object's mass (and inertia) x or / this
    friction_factor: float = 1.0  # its sliding friction (object-table contact) x or / this
    rod_radius: float = 0.0  # m: the push rod's radius error, + or -
    rod_length: float = 0.0  # m: its length error, + or - (the end at the flange stays put)
    sample: Literal["fixed", "uniform"] = "fixed"

    def __post_init__(self):
        for name, (_, lo, hi) in _RANGES.items():
            v = getattr(self, name)
            whole = name in ("mask_open_close", "latency")
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ConfigError(f"env.perturb.{name} must be a number, got {v!r}")
            if not lo <= v <= hi:  # also refuses NaN
                raise ConfigError(f"env.perturb.{name} must be in [{lo}, {hi}], got {v!r}")
            if whole and int(v) != v:
                raise ConfigError(f"env.perturb.{name} must be a whole number, got {v!r}")
            object.__setattr__(self, name, int(v) if whole else float(v))
        if self.frame_repeat + self.frame_empty > 1:
            raise ConfigError(
                f"env.perturb.frame_repeat + env.perturb.frame_empty must be <= 1, got "
                f"{self.frame_repeat} + {self.frame_empty}"
            )
        if self.sample not in SAMPLES:
            raise ConfigError(f"env.perturb.sample must be one of {SAMPLES}, got {self.sample!r}")

    def active(self) -> frozenset[str]:
        """The fields away from their neutral value: the code an environment runs (static under jit)."""
        return frozenset(n for n, (neutral, _, _) in _RANGES.items() if getattr(self, n) != neutral)

    def replace(self, **fields) -> PerturbConfig:
        return dataclasses.replace(self, **fields)

    def merge(self, other: PerturbConfig) -> PerturbConfig:
        """Each field at the larger magnitude of the two (mask_edge: the larger |value|): a config
        whose code covers both (the stress suite compiles one environment for all its cells)."""
        out = {}
        for n, (neutral, _, _) in _RANGES.items():
            a, b = getattr(self, n), getattr(other, n)
            out[n] = a if abs(a - neutral) >= abs(b - neutral) else b
        return dataclasses.replace(self, **out)


# --- the stress suite's rows and levels ---------------------------------------------------------------
# name -> {field: (mild, realistic, severe)}. docs/robustness.md says why each level.
SUITE: dict[str, dict[str, tuple]] = {
    "mask_flip": {"mask_flip": (0.001, 0.003, 0.01)},
    "mask_erode": {"mask_edge": (-0.5, -1.0, -2.0)},
    "mask_dilate": {"mask_edge": (0.5, 1.0, 2.0)},
    "mask_open_close": {"mask_open_close": (1, 1, 2)},  # the reference's real 3 x 3 at mild and realistic
    "frame_repeat": {"frame_repeat": (0.01, 0.05, 0.2)},
    "frame_empty": {"frame_empty": (0.01, 0.05, 0.2)},
    "camera": {"camera_shift": (0.002, 0.005, 0.01), "camera_yaw": (0.009, 0.0175, 0.035)},  # rad: about 0.5, 1, 2 deg
    "latency": {"latency": (10, 30, 60)},
    "flange_noise": {"flange_noise": (0.0005, 0.001, 0.002)},
    "velocity_gain": {"velocity_gain": (0.05, 0.1, 0.2)},
    "velocity_lag": {"velocity_lag": (5.0, 10.0, 30.0)},
    "mass": {"mass_factor": (1.5, 2.0, 4.0)},
    "friction": {"friction_factor": (1.2, 1.5, 2.0)},
    "rod": {"rod_radius": (0.0005, 0.001, 0.002), "rod_length": (0.0005, 0.001, 0.002)},
}
# Rows that change the physics: the only ones a ground-truth reader (the scripted expert) can feel.
PHYSICAL = frozenset({"latency", "velocity_gain", "velocity_lag", "mass", "friction", "rod"})


def suite_config(names, level: str, sample: str = "fixed") -> PerturbConfig:
    """The suite's rows `names` at `level`, all at once (a later row's field wins over an earlier one's:
    of "mask_erode" and "mask_dilate" the one listed last)."""
    if level not in LEVELS:
        raise ConfigError(f"level must be one of {LEVELS}, got {level!r}")
    fields = {}
    for name in names:
        if name not in SUITE:
            raise ConfigError(f"perturbation must be one of {tuple(SUITE)}, got {name!r}")
        fields.update({f: v[LEVELS.index(level)] for f, v in SUITE[name].items()})
    return PerturbConfig(sample=sample, **fields)


def training_config(level: str = "realistic") -> PerturbConfig:
    """Training-time randomisation: every row at `level`, drawn uniformly up to it per episode (erosion
    and dilation alike: |mask_edge| either way)."""
    return suite_config(tuple(n for n in SUITE if n != "mask_erode"), level, "uniform")


def set_line(cfg: PerturbConfig) -> str:
    """The `--set` arguments that give a run `cfg` (its non-neutral fields, exactly, and the sampling)."""
    items = [f"env.perturb.{n}={getattr(cfg, n)!r}" for n in FIELDS if n in cfg.active()]
    items.append(f"env.perturb.sample={cfg.sample}")
    return "--set " + " ".join(items)


# --- one episode's record -------------------------------------------------------------------------------
N_UNIFORMS = 16  # uniforms in [0, 1) per episode that `draw_episode` turns into a record
EPISODE_KEYS = (
    "camera",  # (3,): camera offset x, y (m) and yaw (rad)
    "latency",  # substeps
    "gain",  # velocity tracking factor
    "lag",  # first-order lag: the fraction of the last applied velocity kept per substep
    "mass",  # factors on mass and inertia, on sliding friction
    "friction",
    "rod",  # (2,): radius and length errors (m)
    "flip",  # per-frame rates and levels
    "edge",
    "open_close",
    "repeat",
    "empty",
    "flange_noise",
)


def _sign(u, xp):
    return xp.where(u < 0.5, -1.0, 1.0)


def draw_episode(cfg: PerturbConfig, u, *, xp=np) -> dict:
    """One episode's record from `u` (..., N_UNIFORMS) uniforms in [0, 1). Leading dimensions batch."""
    u = xp.asarray(u, dtype=float)
    uniform = cfg.sample == "uniform"  # a static choice

    def signed(level, k):  # fixed: +-level; uniform: U[-level, level]
        return level * (2 * u[..., k] - 1) if uniform else level * _sign(u[..., k], xp)

    def up_to(level, k):  # fixed: level; uniform: U[0, level]
        return level * u[..., k] if uniform else level + 0.0 * u[..., k]

    def factor(f, k):  # fixed: f or 1/f; uniform: log-uniform in [1/f, f]
        if uniform:
            return xp.exp(math.log(f) * (2 * u[..., k] - 1))
        return xp.where(u[..., k] < 0.5, 1.0 / f, f + 0.0 * u[..., k])

    def whole(level, k):  # fixed: level; uniform: an integer in [0, level]
        return xp.floor(u[..., k] * (level + 1)) if uniform else level + 0.0 * u[..., k]

    theta = 2 * math.pi * u[..., 0]
    shift = up_to(cfg.camera_shift, 2)
    edge = signed(abs(cfg.mask_edge), 11) if uniform else cfg.mask_edge + 0.0 * u[..., 11]
    tau = up_to(cfg.velocity_lag, 5)
    return {
        "camera": xp.stack([shift * xp.cos(theta), shift * xp.sin(theta), signed(cfg.camera_yaw, 1)], axis=-1),
        "latency": whole(cfg.latency, 3),
        "gain": 1.0 + signed(cfg.velocity_gain, 4),
        "lag": tau / (tau + 1.0),  # one substep is 1 ms
        "mass": factor(cfg.mass_factor, 6),
        "friction": factor(cfg.friction_factor, 7),
        "rod": xp.stack([signed(cfg.rod_radius, 8), signed(cfg.rod_length, 9)], axis=-1),
        "flip": up_to(cfg.mask_flip, 10),
        "edge": edge,
        "open_close": whole(cfg.mask_open_close, 12),
        "repeat": up_to(cfg.frame_repeat, 13),
        "empty": up_to(cfg.frame_empty, 14),
        "flange_noise": up_to(cfg.flange_noise, 15),
    }


def neutral_episode(*, xp=np) -> dict:
    """A record that changes nothing (what `draw_episode` gives for a neutral config)."""
    return draw_episode(PerturbConfig(), xp.zeros(N_UNIFORMS), xp=xp)


# --- the object and the rod ---------------------------------------------------------------------------
def scale_object(params, episode: dict, *, xp=np):
    """The object with its mass and inertia (the same shape, so inertia scales with mass) and its sliding
    friction scaled by the record's factors. `mjx_push.objects.apply` (MJX) and `mj_setConst` (CPU)
    recompute what MuJoCo derives from them."""
    f = episode["friction"]
    mu = xp.maximum(params.friction[..., 0] * f, scene.MIN_OBJECT_FRICTION)
    friction = xp.concatenate([mu[..., None], params.friction[..., 1:]], axis=-1)
    m = episode["mass"]
    return params.replace(mass=params.mass * m, inertia=params.inertia * m[..., None], friction=friction)


def rod_geometry(size, pos, rbound, aabb, rod, *, xp=np):
    """The rod capsule's (size (3,), pos (3,), rbound, aabb (6,)) with its radius and length off by
    `rod` (2,) from the nominal ones given. Its end at the flange stays put (the body's +z points to
    the tip). Mass and inertia stay as built: a millimetre changes them by about one percent on an arm
    whose joints are velocity-servoed."""
    dr, dl = rod[0], rod[1]
    size = size + xp.stack([dr, dl / 2, 0.0 * dr])
    pos = pos + xp.stack([0.0 * dr, 0.0 * dr, dl / 2])
    aabb = aabb + xp.stack([0.0 * dr, 0.0 * dr, 0.0 * dr, dr, dr, dr + dl / 2])
    return size, pos, rbound + dr + dl / 2, aabb


# --- the camera -----------------------------------------------------------------------------------------
def camera_view(xy, yaw, camera, *, xp=np):
    """The pose (xy, yaw) at which the nominal camera would see what a camera displaced by `camera`
    (dx, dy, dyaw) sees of an object at (xy, yaw): xy' = c + R(-dyaw) (xy - c - d), yaw' = yaw - dyaw,
    with c the camera's nominal position. Written as xy - d plus a rotation term that is exactly zero
    at dyaw = 0."""
    c = xp.asarray(scene.CAMERA_POS[:2], dtype=float)
    d = xp.asarray(xy, dtype=float) - c - camera[..., :2]
    psi = camera[..., 2]
    s, vers = xp.sin(psi), -2.0 * xp.sin(psi / 2) ** 2  # sin, cos - 1
    rot = xp.stack([vers * d[..., 0] + s * d[..., 1], -s * d[..., 0] + vers * d[..., 1]], axis=-1)
    return xp.asarray(xy, dtype=float) - camera[..., :2] + rot, yaw - psi


# --- masks ----------------------------------------------------------------------------------------------
def _window3(mask, pad_value: bool, op, xp):
    # A 3 x 3 square is separable: three rows, then three columns.
    n0, n1 = mask.shape[-2], mask.shape[-1]
    p = xp.pad(mask, [(0, 0)] * (mask.ndim - 2) + [(1, 1), (0, 0)], constant_values=pad_value)
    out = op(op(p[..., :n0, :], p[..., 1 : n0 + 1, :]), p[..., 2 : n0 + 2, :])
    p = xp.pad(out, [(0, 0)] * (mask.ndim - 2) + [(0, 0), (1, 1)], constant_values=pad_value)
    return op(op(p[..., :n1], p[..., 1 : n1 + 1]), p[..., 2 : n1 + 2])


def erode(mask, n: int = 1, *, xp=np):
    """n erosions with a 3 x 3 square (outside the image counts as object, as in
    `mjx_push.export.camera.erode`)."""
    for _ in range(n):
        mask = _window3(mask, True, lambda a, b: a & b, xp)
    return mask


def dilate(mask, n: int = 1, *, xp=np):
    """n dilations with a 3 x 3 square (outside the image counts as background)."""
    for _ in range(n):
        mask = _window3(mask, False, lambda a, b: a | b, xp)
    return mask


def edge(mask, k, k_max: int, *, xp=np):
    """Dilation by k pixels (erosion for k < 0), k a whole number in [-k_max, k_max] (traced under jit;
    k_max static)."""
    out, eroded, dilated = mask, mask, mask
    for j in range(1, k_max + 1):
        eroded, dilated = erode(eroded, xp=xp), dilate(dilated, xp=xp)
        out = xp.where(k == -j, eroded, xp.where(k == j, dilated, out))
    return out


def open_close(mask, r, r_max: int, *, xp=np):
    """Opening then closing with a (2r+1)^2 square (r fold 3 x 3), r in [0, r_max] (traced)."""
    out = mask
    for j in range(1, r_max + 1):
        opened = dilate(erode(mask, j, xp=xp), j, xp=xp)
        closed = erode(dilate(opened, j, xp=xp), j, xp=xp)
        out = xp.where(r == j, closed, out)
    return out


def frame_edge(level, u, *, xp=np):
    """This frame's whole-pixel edge change for a level: sign(level) (floor|level| + [u < frac|level|])."""
    a = xp.abs(level)
    whole = xp.floor(a)
    return xp.sign(level) * (whole + (u < a - whole))


def camera_mask(mask, episode: dict, u_edge, u_pixels, k_max: int, r_max: int, *, xp=np):
    """What the real pipeline would deliver for the ideal mask `mask` (64, 64): the edge off by this
    frame's pixels, pixels flipped at the record's rate (`u_pixels` (64, 64) uniforms, or None when no
    flips can happen), then the pipeline's opening and closing."""
    if k_max:
        mask = edge(mask, frame_edge(episode["edge"], u_edge, xp=xp), k_max, xp=xp)
    if u_pixels is not None:
        mask = mask ^ (u_pixels < episode["flip"])
    if r_max:
        mask = open_close(mask, episode["open_close"], r_max, xp=xp)
    return mask


def missed_frame(mask, shown, episode: dict, u, *, xp=np):
    """A missed frame, with probability `episode["empty"]` an empty mask, with `episode["repeat"]` the
    last mask shown again (`shown`), else `mask`."""
    empty = u < episode["empty"]
    repeat = (u >= episode["empty"]) & (u < episode["empty"] + episode["repeat"])
    return xp.where(empty, False, xp.where(repeat, shown, mask))


# --- the arm --------------------------------------------------------------------------------------------
def actuate(dq, applied, episode: dict, *, xp=np):
    """The joint velocities the servos get for the controller's `dq`: scaled by the tracking gain and
    lagged behind the last applied velocities `applied` (first order, one substep per call)."""
    x = dq * episode["gain"]
    return x + episode["lag"] * (applied - x)

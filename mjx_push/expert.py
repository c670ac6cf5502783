"""A scripted pusher that reads the simulator's ground truth: the task's baseline and the learner's
source of demonstrations.

It knows what no policy observes (the object's exact pose, size and shape, the goal, the flange's
true position) and plans one environment step at a time, in three modes:

* **reposition**: get the rod to a point just behind the object on the goal->object line. If the
  rod is far round the object it travels on a circle clear of it (a few tens of degrees per step;
  the short way, or past ``circle_cut`` always the same side) and goes straight in once it is
  within ``approach_angle`` of the push line.
* **push**: move the rod along the object->goal direction by the remaining distance (or
  ``push_fraction`` of it), at most ``max_push`` per step (slow enough that light objects decelerate
  with the rod instead of sliding on), with a sideways correction that keeps the rod on the line
  through the object's centre.
* **hold**: once the object is within ``hold_radius`` of the goal, stand still (short steps, or with
  ``hold_short`` off steps as long as the other modes', so a_s does not jump at the hold radius).

Every mode asks for a flange *displacement* D and a step length n (substeps). The controller
drives the flange towards ``ee + offset`` with a first-order response, so the expert inverts the
measured step response ``frac(n) = 1 - exp(-k (n - n0))`` with ``k = response_rate * gain`` and
sends ``offset = D / frac(n)``, clipped to the action box; n is the shortest step that reaches
``settle`` of the offset, clipped to the environment's substep range. So it works (less well) under
any action box, the paper's included.

Everything is a pure function of one environment's ground truth (vmap it for a batch).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from mjx_push import scene
from mjx_push.env import EnvConfig
from mjx_push.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class ExpertConfig:
    gap: float = 0.004  # rod surface to object surface when lining up behind it (m)
    clearance: float = 0.015  # rod surface to the object's bounding circle while going round it (m)
    approach_angle: float = 0.6  # rad: within this of the push line, go straight to the push point
    line_tolerance: float = 0.35  # rad: pushing continues while the rod is this close to the line
    # Where (angle off the push line, rad) the way round the object changes side. pi: the short way,
    # but then a rod right in front of the object (where it stands after an overshoot) goes round
    # either side on a hair's difference, and a cloner averages the two into standing still. Below
    # pi, every angle beyond it goes round the same side as the angles just short of it.
    circle_cut: float = math.pi
    max_move: float = 0.05  # m per step while repositioning
    max_push: float = 0.02  # m per step while pushing
    push_lead: float = 0.0  # m pushed beyond the remaining distance (heavy objects lag the rod)
    # Each push covers this fraction of the remaining distance (1: all of it). Below 1 the object
    # closes on its goal geometrically, so a light one that slides on after the rod stops overshoots
    # less, and a cloner's error in the distance it reads costs less.
    push_fraction: float = 1.0
    hold_radius: float = 0.003  # m: closer than this, stand still
    # Stand still with the shortest step (True) or with the other modes' step length (False): the same
    # stillness, but a cloner's a_s label no longer jumps from about 0.8 to -1 at the hold radius.
    hold_short: bool = True
    settle: float = 0.9  # fraction of the offset a step should reach
    # Step response of the controller per substep and unit gain, and its dead time in substeps
    # (fitted on the MJX scene: gains 5-20, offsets of a few centimetres).
    response_rate: float = 7.5e-4
    dead_substeps: float = 30.0

    def __post_init__(self):
        for name in ("gap", "clearance", "max_move", "max_push", "hold_radius", "response_rate"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"expert.{name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.settle < 1:
            raise ConfigError(f"expert.settle must be in (0, 1), got {self.settle}")
        if not isinstance(self.hold_short, bool):
            raise ConfigError(f"expert.hold_short must be a bool, got {self.hold_short!r}")
        if not 0 < self.circle_cut <= math.pi:
            raise ConfigError(f"expert.circle_cut must be in (0, pi], got {self.circle_cut}")
        if not 0 < self.push_fraction <= 1:
            raise ConfigError(f"expert.push_fraction must be in (0, 1], got {self.push_fraction}")
        if self.push_lead < 0 or self.dead_substeps < 0:
            raise ConfigError("expert.push_lead and expert.dead_substeps must be >= 0")


def support(size: jax.Array, is_box: jax.Array, yaw: jax.Array, d: jax.Array) -> jax.Array:
    """Extent of the object's footprint from its centre along unit direction d (support function)."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    box = size[0] * jnp.abs(d[0] * c + d[1] * s) + size[1] * jnp.abs(-d[0] * s + d[1] * c)
    return jnp.where(is_box, box, size[0])


def bounding_radius(size: jax.Array, is_box: jax.Array) -> jax.Array:
    return jnp.where(is_box, jnp.hypot(size[0], size[1]), size[0])


def _unit(v: jax.Array, fallback: jax.Array) -> jax.Array:
    n = jnp.linalg.norm(v)
    return jnp.where(n > 1e-9, v / jnp.maximum(n, 1e-9), fallback)


def _rot(v: jax.Array, a: jax.Array) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    return jnp.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]])


# The modes `plan` chooses among, by index (`mode`): the cloning error splits along them
# (benchmarks/bc_gap.py), since the expert's action jumps where it switches mode.
MODES = ("hold", "push", "approach", "circle")


def act(cfg: ExpertConfig, env: EnvConfig, gt: dict) -> jax.Array:
    """The action (a_x, a_y, a_s) in [-1, 1]^3 for one environment. ``gt`` holds ``ee_xy`` (true flange
    xy), ``object_xy``, ``object_yaw``, ``goal_xy``, ``size`` (the geom size: box half extents or
    cylinder radius first) and ``is_box``."""
    disp, m = plan(cfg, gt)
    return displacement_action(cfg, env, disp, short=(m == 0) & cfg.hold_short)


def mode(cfg: ExpertConfig, gt: dict) -> jax.Array:
    """The index into MODES of the mode the expert acts in for one environment's ``gt``."""
    return plan(cfg, gt)[1]


def plan(cfg: ExpertConfig, gt: dict) -> tuple[jax.Array, jax.Array]:
    """The flange displacement the expert asks for, and the index into MODES of the mode it chose."""
    ee, obj, goal = gt["ee_xy"], gt["object_xy"], gt["goal_xy"]
    size, is_box, yaw = gt["size"], gt["is_box"], gt["object_yaw"]
    rod = scene.ROD_RADIUS

    to_goal = goal - obj
    dist = jnp.linalg.norm(to_goal)
    rel = ee - obj
    u = _unit(to_goal, _unit(-rel, jnp.array([1.0, 0.0])))  # push direction
    n = jnp.stack([-u[1], u[0]])
    behind_r = support(size, is_box, yaw, -u) + rod  # rod centre touching the object from behind

    # Where the rod is, seen from the object: angle off the push line (0: right behind it).
    off = jnp.arctan2(jnp.dot(rel, n), -jnp.dot(rel, u))  # in (-pi, pi]
    on_line = (jnp.abs(off) < cfg.line_tolerance) & (jnp.dot(rel, -u) < behind_r + 2 * cfg.gap + 0.01)

    # Push: the remaining distance along u, capped; slide sideways onto the line through the centre.
    lateral = jnp.dot(rel, n)
    push = u * jnp.minimum(cfg.push_fraction * dist + cfg.push_lead, cfg.max_push) - 0.5 * lateral * n

    # Reposition: straight to the push point when nearly behind, else round the object on a circle.
    push_point = obj - u * (behind_r + cfg.gap)
    circle_r = bounding_radius(size, is_box) + rod + cfg.clearance
    step_angle = cfg.max_move / circle_r
    # (-u, n) is a left-handed frame: turning rel counter-clockwise by a lowers off by a.
    # The signed angle still to turn: off itself (the short way), or the long way past the cut.
    to_turn = jnp.where(off > cfg.circle_cut, off - 2 * jnp.pi, off)
    turn = jnp.clip(to_turn, -step_angle, step_angle)  # towards off = 0, never across the cut
    way = obj + circle_r * _rot(_unit(rel, -u), turn)
    straight = jnp.abs(off) < cfg.approach_angle
    move = jnp.where(straight, push_point - ee, way - ee)
    move = move * jnp.minimum(1.0, cfg.max_move / jnp.maximum(jnp.linalg.norm(move), 1e-9))

    hold = dist < cfg.hold_radius
    disp = jnp.where(hold, jnp.zeros(2), jnp.where(on_line, push, move))
    m = jnp.where(hold, 0, jnp.where(on_line, 1, jnp.where(straight, 2, 3)))
    return disp, m


def displacement_action(cfg: ExpertConfig, env: EnvConfig, disp: jax.Array, short: jax.Array) -> jax.Array:
    """Action whose step moves the flange by about ``disp``: the step length that settles to
    ``cfg.settle`` of its offset (or the shortest one when ``short``) and the offset that, at that
    length, covers ``disp``; both clipped to the action box."""
    lo, hi = env.substeps
    k = cfg.response_rate * env.controller.gain
    n_settle = cfg.dead_substeps - jnp.log(1.0 - cfg.settle) / k
    n = jnp.where(short, lo, jnp.clip(jnp.ceil(n_settle), lo, hi))
    frac = jnp.clip(1.0 - jnp.exp(-k * (n - cfg.dead_substeps)), 0.05, 1.0)
    a_xy = jnp.clip(disp / frac / env.action_scale, -1.0, 1.0)
    a_s = 2.0 * (n + 0.5 - lo) / max(hi - lo, 1) - 1.0
    return jnp.concatenate([a_xy, jnp.clip(a_s, -1.0, 1.0)[None]])


def ground_truth(info: dict, size: jax.Array, is_box) -> dict:
    """The expert's inputs from a `PushEnv` state's info (one environment, or a batch with leading axes)."""
    return {
        "ee_xy": info["ee_xy_true"],
        "object_xy": info["object_xy"],
        "object_yaw": info["object_yaw"],
        "goal_xy": info["goal_xy"],
        "size": size,
        "is_box": jnp.asarray(is_box),
    }

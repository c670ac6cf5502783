"""Deployment loop: a trained policy pushes an object with a robot behind a small interface.

    from mjx_push.export.camera import MaskPipeline
    from mjx_push.export.deploy import run_episode
    result = run_episode(policy, robot, camera, MaskPipeline(...), goal_mask)

Per step, exactly as the simulator: camera frame -> `MaskPipeline.to_mask` -> `policy.act(object_mask,
goal_mask, ee_xy)` -> flange target = ee_xy + (a_x, a_y) * action_scale clipped to the workspace, z at the
home flange height (`mjx_push.task_rules.flange_target`, the function both simulators use) ->
`robot.move_to` -> `robot.wait_ms(a_s)` (one simulator substep is 1 ms, so the policy's a_s substeps are
a_s milliseconds).

Interfaces (`typing.Protocol`, so any object with these methods fits):
- `Robot`: `flange_xy()`, `move_to(xyz)` (sets the target the robot's controller drives the flange to and
  returns at once), `wait_ms(n)` (lets the controller run for n ms), `home()`.
- `Camera`: `frame()` -> RGB uint8 (H, W, 3).
- `Policy`: `reset()`, `act(object_mask, goal_mask, ee_xy)` -> (a_x, a_y, a_s_substeps) with a_x, a_y in
  [-1, 1] and a_s_substeps the decoded integer substep count (the exported NumPy policy follows this).

`SimRobot` and `SimCamera` put a `CpuPushEnv` behind these interfaces (robot: the environment's own
controller at every 1 ms substep; camera: the rendered under-table view, which the default
`MaskPipeline` turns back into the simulator's mask), so the whole loop can be tested without hardware.

Connecting a real Panda (no robot library is imported by this package; full notes in docs/deploy.md):
implement `Robot` with panda-py, running the simulator's own task-space velocity law
(`mjx_push.control_law.law`) at 1 kHz in panda-py's joint-velocity controller, so the real arm follows
targets as the simulated one does; `export/panda_py_robot.py` is a sketch of that class.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from mjx_push.export.camera import MaskPipeline
from mjx_push.export.cpu_env import CpuPushEnv
from mjx_push import scene
from mjx_push.config import EnvConfig
from mjx_push.errors import ConfigError
from mjx_push.task_rules import flange_target, sanitize_action

_DEFAULTS = EnvConfig()
DEFAULT_WORKSPACE = (_DEFAULTS.workspace_x, _DEFAULTS.workspace_y)  # ((x_low, x_high), (y_low, y_high))
MAX_WAIT_MS = _DEFAULTS.substeps[1]


@runtime_checkable
class Robot(Protocol):
    def flange_xy(self) -> np.ndarray:
        """Measured flange position xy (2,) in the robot base frame, metres."""

    def move_to(self, target: np.ndarray) -> None:
        """Set the flange target (3,) (x, y, z); returns at once, the controller keeps driving the flange."""

    def wait_ms(self, n: int) -> None:
        """Let the controller run for n milliseconds."""

    def home(self) -> None:
        """Return to the home configuration (mjx_push.scene.HOME_QPOS)."""


@runtime_checkable
class Camera(Protocol):
    def frame(self) -> np.ndarray:
        """The current RGB image (H, W, 3) uint8 from under the table."""


@runtime_checkable
class Policy(Protocol):
    def reset(self) -> None:
        """Start of an episode (clears recurrent state and observation history)."""

    def act(self, object_mask: np.ndarray, goal_mask: np.ndarray, ee_xy: np.ndarray) -> tuple[float, float, int]:
        """(a_x, a_y, a_s_substeps) from bool (64, 64) masks and the flange xy (2,)."""


def _check_workspace(workspace) -> tuple[tuple[float, float], tuple[float, float]]:
    try:
        (x0, x1), (y0, y1) = workspace
    except (TypeError, ValueError):
        raise ConfigError(f"workspace must be ((x_low, x_high), (y_low, y_high)), got {workspace!r}") from None
    if not (x0 < x1 and y0 < y1):
        raise ConfigError(f"workspace must have low < high on both axes, got {workspace!r}")
    return (float(x0), float(x1)), (float(y0), float(y1))


def _check_mask(name: str, mask) -> np.ndarray:
    mask = np.asarray(mask)
    n = scene.IMAGE_SIZE
    if mask.shape != (n, n):
        raise ConfigError(f"{name} must have shape ({n}, {n}), got {mask.shape}")
    return mask.astype(bool)


def run_episode(
    policy: Policy,
    robot: Robot,
    camera: Camera,
    pipeline: MaskPipeline,
    goal_mask: np.ndarray,
    steps: int = 50,
    action_scale: float = 1.0,
    workspace=DEFAULT_WORKSPACE,
    home_z: float | None = None,
    max_wait_ms: int = MAX_WAIT_MS,
    on_step: Callable[[int, dict], bool | None] | None = None,
) -> dict:
    """Run one episode of `steps` policy steps and return its record.

    Policy outputs are handled like the simulator's actions: non-finite a_x, a_y become 0 and are counted
    ("bad_actions"), the rest is clipped to [-1, 1]; a_s_substeps must be an integer in [1, max_wait_ms]
    (ValueError otherwise: a wrong wait on a real robot is not something to guess about). `home_z`
    defaults to the simulator's home flange height. `on_step(t, record)` is called after every step with
    that step's record; returning True stops the episode early (e.g. an operator abort).

    Returns a dict of arrays: "ee_xy" (T+1, 2) measured before every step and at the end, "object_masks"
    (T+1, 64, 64), "actions" (T, 3) as (a_x, a_y, a_s_substeps) after sanitising, "targets" (T, 3),
    "goal_mask", "bad_actions" and "steps" (T, the number of steps run)."""
    if not isinstance(pipeline, MaskPipeline):
        raise ConfigError(f"pipeline must be an mjx_push.export.camera.MaskPipeline, got {type(pipeline).__name__}")
    goal_mask = _check_mask("goal_mask", goal_mask)
    if not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ConfigError(f"steps must be an integer >= 1, got {steps!r}")
    if not action_scale > 0:
        raise ConfigError(f"action_scale must be > 0, got {action_scale!r}")
    wx, wy = _check_workspace(workspace)
    home_z = float(scene.home_flange_pos()[2] if home_z is None else home_z)
    if not isinstance(max_wait_ms, (int, np.integer)) or max_wait_ms < 1:
        raise ConfigError(f"max_wait_ms must be an integer >= 1, got {max_wait_ms!r}")

    policy.reset()
    ee_hist, masks, actions, targets = [], [], [], []
    bad_actions = 0
    for t in range(steps):
        ee = np.asarray(robot.flange_xy(), np.float64).reshape(2)
        mask = pipeline.to_mask(camera.frame())
        a_x, a_y, a_s = policy.act(mask, goal_mask, ee)
        a_xy, bad = sanitize_action(np.array([a_x, a_y], np.float64))
        bad_actions += int(bad)
        if isinstance(a_s, (bool, np.bool_)) or not float(a_s).is_integer() or not 1 <= a_s <= max_wait_ms:
            raise ConfigError(f"policy a_s_substeps must be an integer in [1, {max_wait_ms}], got {a_s!r} at step {t}")
        a_s = int(a_s)
        target = flange_target(ee, a_xy, action_scale, wx, wy, home_z)
        robot.move_to(target)
        robot.wait_ms(a_s)
        ee_hist.append(ee)
        masks.append(mask)
        actions.append([a_xy[0], a_xy[1], a_s])
        targets.append(target)
        if on_step is not None and on_step(
            t, {"ee_xy": ee, "object_mask": mask, "action": actions[-1], "target": target}
        ):
            break
    ee_hist.append(np.asarray(robot.flange_xy(), np.float64).reshape(2))
    masks.append(pipeline.to_mask(camera.frame()))
    return {
        "ee_xy": np.stack(ee_hist),
        "object_masks": np.stack(masks),
        "actions": np.asarray(actions, np.float64),
        "targets": np.stack(targets),
        "goal_mask": goal_mask,
        "bad_actions": bad_actions,
        "steps": len(actions),
    }


class SimRobot:
    """`Robot` on a shared `CpuPushEnv` (reset it first): `move_to` sets the environment's controller
    target, `wait_ms(n)` runs n 1 ms substeps of physics with the controller (corrections are counted in
    the environment as usual), `home()` drives the flange back to the home position for `home_ms`."""

    def __init__(self, env: CpuPushEnv, home_ms: int = 1500):
        self.env = env
        self.home_ms = int(home_ms)

    def flange_xy(self) -> np.ndarray:
        return self.env.flange_pos()[:2]

    def move_to(self, target: np.ndarray) -> None:
        target = np.asarray(target, np.float64)
        if target.shape != (3,) or not np.all(np.isfinite(target)):
            raise ConfigError(f"target must be a finite (3,) flange position, got {target!r}")
        self.env.target = target.copy()

    def wait_ms(self, n: int) -> None:
        if int(n) < 0:
            raise ConfigError(f"n must be >= 0 milliseconds, got {n!r}")
        self.env.run_substeps(int(n))

    def home(self) -> None:
        self.move_to(self.env.home_flange)
        self.wait_ms(self.home_ms)


class SimCamera:
    """`Camera` on a shared `CpuPushEnv`: the "under_table" view rendered at size x size pixels (64 gives
    the simulator's own mask with the default `MaskPipeline`; larger sizes exercise its resize)."""

    def __init__(self, env: CpuPushEnv, size: int = scene.IMAGE_SIZE):
        self.env = env
        self.size = int(size)

    def frame(self) -> np.ndarray:
        return self.env.render_rgb("under_table", (self.size, self.size))

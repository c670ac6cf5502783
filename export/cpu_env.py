"""The pushing task on CPU MuJoCo (`mujoco.MjData` + `mujoco.mj_step`): one environment, no JAX in the loop.

It is the MJX `mjx_push.env.PushEnv` re-run in C MuJoCo, for evaluation with a real rendered camera, for
Gymnasium users (`mjx_push.export.gym_env`) and as the simulated robot behind the deployment loop
(`mjx_push.export.deploy`). Everything that defines the task is shared or ported line for line:

- the scene: `mjx_push.scene.build_model`, with the object's size, mass, inertia and friction written into
  the `MjModel` as `mjx_push.objects.apply` does for MJX, then `mujoco.mj_setConst` (which derives the
  inverse weights exactly instead of the MJX approximation);
- the configuration: `mjx_push.config.EnvConfig` (objects, controller, solver, action scale, substep
  range, episode length, tau, observation noise, workspace, out-of-bounds band);
- the step: action sanitising, workspace clip and a_s -> substeps decoding (`mjx_push.task_rules`, the
  functions `PushEnv.begin_step` runs with JAX; decoded in float32, like the MJX environment, so the same
  a_s gives the same count); the controller (`mjx_push.control_law` on MjData's kinematics,
  `mjx_push.export.controller_np`) at every 1 ms substep or held per step; the correction counters
  (`mjx_push.export.corrections_np`, the rule of `mjx_push.task_rules`) at every substep; the validity check of
  `PushEnv._valid`, an invalid state being replaced by the episode's initial state. One addition: C
  MuJoCo silently resets `MjData` to the model's default pose when qpos, qvel or qacc become non-finite
  or huge (MJX lets the NaN through), so a step during which MuJoCo raised one of those warnings is
  invalid as well.
- substep ordering: the controller reads the kinematics that the previous `mj_step` left in `MjData`
  (mj_step computes them before integrating), exactly as the MJX loop reads `mjx.step`'s output; the
  flange xy of the observation and of `info["ee_xy_true"]` comes from the same place (one substep old).

Perturbations of a real cell (`config.perturb`, off by default; `mjx_push.perturb`, docs/robustness.md)
run here as in the MJX environment, from the same functions: the record drawn at reset scales the
object's mass and friction and moves the rod's geometry and the "under_table" camera in the `MjModel`
(so rendered masks see the camera offset too); each observation passes the masks through the real
pipeline's errors and adds flange noise; each step runs the previous target for the latency's first
substeps and the servo's gain and lag at every substep. With `controller.hold_per_step` the late
substeps hold the previous target's law evaluated at the step's start (MJX holds the previous
step's command). Their random draws are the environment's own (NumPy), not MJX's.

Masks (`mask_source`):
- "render": the "under_table" camera rendered by `mujoco.Renderer` at 64x64, colour-filtered with
  `render_filter` (the object's emissive blue: B > 128, R < 80, G < 80; nothing else in the scene is
  blue, the glass table is invisible and the arm is grey). Needs an OpenGL context: on a Linux machine
  without a display, `import export` (or `import mjx_push`) selects EGL before mujoco is imported.
- "analytic": `mjx_push.mask_geometry` with NumPy, the masks MJX computes with JAX (no renderer, no JAX).
- "auto" (default): "render" if a renderer can be created, else "analytic" (see `mask_source_used`).

Object parameters are drawn with `mjx_push.objects.sample` (JAX, jitted once per shape and config) from
a key seeded by the environment's NumPy generator, unless `reset` is given an `ObjectParams`: only that
draw imports JAX (on first use); everything else here runs without it.
"""

from __future__ import annotations

import functools
import math
import warnings
import weakref
from dataclasses import dataclass

import mujoco
import numpy as np

from mjx_push.export import controller_np as ctl
from mjx_push.export import corrections_np as corr
from mjx_push import mask_geometry, perturb, scene, task_rules
from mjx_push.config import EnvConfig, ObjectConfig, ObjectParams
from mjx_push.config import half_height as _half_height

# The step's rules, shared with the MJX environment (NumPy by default; importable from here as before).
from mjx_push.task_rules import flange_target, quat_yaw, sanitize_action, yaw_quat
from mjx_push.task_rules import substep_count as decode_substeps
from mjx_push.renderer import new_renderer, renderer_available, unavailable_reason  # noqa: F401
from mjx_push.errors import ConfigError

MASK_SOURCES = ("render", "analytic", "auto")
CAMERAS = ("under_table", "top")
# Colour filter for the rendered under-table view: the object's material is pure blue and emissive, so
# it renders at about (0, 0, 255) whatever the lighting; grey arm and rod pixels fail the R/G bound.
BLUE_MIN = 128  # B > BLUE_MIN
RED_GREEN_MAX = 80  # R < RED_GREEN_MAX and G < RED_GREEN_MAX
MAX_RENDER_SIZE = (480, 640)  # (height, width): the scene's offscreen buffer
_UNSTABLE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)


# One place creates renderers and remembers a failure for the process (MuJoCo aborts on a second try).
_new_renderer = new_renderer


def render_filter(rgb: np.ndarray) -> np.ndarray:
    """Object mask (H, W) bool from a rendered under-table RGB frame (H, W, 3) uint8."""
    rgb = np.asarray(rgb).astype(np.int32)
    return (rgb[..., 2] > BLUE_MIN) & (rgb[..., 0] < RED_GREEN_MAX) & (rgb[..., 1] < RED_GREEN_MAX)


def params_to_numpy(params: ObjectParams) -> ObjectParams:
    """An `ObjectParams` with float64 NumPy leaves (accepts JAX or NumPy arrays), shapes checked."""
    shapes = {"size": (3,), "mass": (), "inertia": (3,), "friction": (3,), "start": (3,), "goal": (3,)}
    out = {}
    for name, shape in shapes.items():
        v = np.asarray(getattr(params, name), dtype=np.float64)
        if v.shape != shape:
            raise ConfigError(f"params.{name} must have shape {shape}, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ConfigError(f"params.{name} must be finite, got {v}")
        out[name] = v
    if np.any(out["size"][:2] <= 0) or out["mass"] <= 0 or np.any(out["inertia"] <= 0):
        raise ConfigError("params.size, params.mass and params.inertia must be positive")
    return ObjectParams(**out)


def half_height(params: ObjectParams, geom_type: str) -> float:
    return float(_half_height(params, geom_type))


def apply_params(
    m: mujoco.MjModel, d: mujoco.MjData, params: ObjectParams, ids: scene.SceneIds, geom_type: str
) -> None:
    """Write the object's size, friction, mass and inertia into `m` (as `objects.apply` does for MJX) and
    let `mj_setConst` recompute what MuJoCo derives from them (inverse weights, subtree masses; MJX
    approximates those instead, which is why the two writers stay apart)."""
    g, b = ids.object_geom, ids.object_body
    size = params.size
    rbound, aabb_half = task_rules.object_bounds(size, geom_type)
    m.geom_size[g] = size
    m.geom_rbound[g] = rbound
    m.geom_aabb[g, 3:] = aabb_half
    m.geom_friction[g] = params.friction
    m.body_mass[b] = params.mass
    m.body_inertia[b] = params.inertia
    mujoco.mj_setConst(m, d)


@functools.lru_cache(maxsize=None)
def _sampler(cfg: ObjectConfig, geom_type: str):
    # Only drawing objects needs JAX: imported here, so the rest of this module (the deployment loop's
    # simulated robot, analytic masks, given objects) runs without it.
    import jax

    from mjx_push import objects

    return jax.jit(lambda key, home: objects.sample(key, cfg, geom_type, home))


def sample_params(seed: int, cfg: ObjectConfig, geom_type: str) -> ObjectParams:
    """One object drawn with `mjx_push.objects.sample` from `jax.random.PRNGKey(seed)` (NumPy leaves)."""
    import jax

    home = np.asarray(scene.home_flange_pos()[:2], np.float32)
    p = _sampler(cfg, geom_type)(jax.random.PRNGKey(seed), home)
    return params_to_numpy(jax.tree.map(np.asarray, p))


def _close_renderers(renderers: dict) -> None:
    for r in renderers.values():
        r.close()
    renderers.clear()


@dataclass
class _ShapeSim:
    """One compiled scene per geom type (CPU MuJoCo may switch shape between episodes)."""

    model: mujoco.MjModel
    data: mujoco.MjData
    scratch: mujoco.MjData  # for renders at other poses (goal) without touching the simulation
    ids: scene.SceneIds
    nominal: dict  # the rod's and the camera's fields as built (perturbations are written from them)


def _nominal(m: mujoco.MjModel, ids: scene.SceneIds) -> dict:
    g, cam = ids.rod_geom, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "under_table")
    rod = {k: getattr(m, k)[g].copy() for k in ("geom_size", "geom_pos", "geom_rbound", "geom_aabb")}
    return {"rod": rod, "camera": cam, "cam_pos": m.cam_pos[cam].copy(), "cam_quat": m.cam_quat[cam].copy()}


def apply_perturbation(m: mujoco.MjModel, sim: _ShapeSim, record: dict) -> None:
    """Write an episode's rod errors and camera offset (`mjx_push.perturb`) into `m`, from the nominal
    values (so episodes never accumulate them). The camera moves by (dx, dy) and turns by dyaw about
    the world z axis, its optical axis: the rendered masks then show what `perturb.camera_view` gives
    the analytic ones."""
    g, nom = sim.ids.rod_geom, sim.nominal
    r = nom["rod"]
    size, pos, rbound, aabb = perturb.rod_geometry(
        r["geom_size"], r["geom_pos"], r["geom_rbound"], r["geom_aabb"], record["rod"]
    )
    m.geom_size[g], m.geom_pos[g], m.geom_rbound[g], m.geom_aabb[g] = size, pos, rbound, aabb
    cam = nom["camera"]
    dx, dy, dyaw = (float(v) for v in record["camera"])
    m.cam_pos[cam] = nom["cam_pos"] + np.array([dx, dy, 0.0])
    turn = np.array([math.cos(dyaw / 2), 0.0, 0.0, math.sin(dyaw / 2)])
    quat = np.empty(4)
    mujoco.mju_mulQuat(quat, turn, nom["cam_quat"])
    m.cam_quat[cam] = quat


class CpuPushEnv:
    """The pushing task on CPU MuJoCo. `geom_type` None draws the shape per episode from the config's
    shape filter (equally likely); "box" or "cylinder" fixes it."""

    def __init__(
        self,
        config: EnvConfig = EnvConfig(),
        geom_type: str | None = None,
        mask_source: str = "auto",
        seed: int | None = None,
    ):
        if not isinstance(config, EnvConfig):
            raise ConfigError(f"config must be an mjx_push.env.EnvConfig, got {type(config).__name__}")
        shapes = config.objects.shapes()
        if geom_type is not None and geom_type not in shapes:
            raise ConfigError(
                f"geom_type must be None or one of {shapes} (shape filter {config.objects.shape!r}), got {geom_type!r}"
            )
        if mask_source not in MASK_SOURCES:
            raise ConfigError(f"mask_source must be one of {MASK_SOURCES}, got {mask_source!r}")
        self.config = config
        self.fixed_geom_type = geom_type
        self.np_random = np.random.default_rng(seed)
        self.home_flange = scene.home_flange_pos().copy()
        self._sims: dict[str, _ShapeSim] = {}
        self._renderers: dict[tuple[str, int, int], mujoco.Renderer] = {}
        # Close GL contexts while the interpreter is still whole (a Renderer's own __del__ at shutdown
        # raises once its modules are torn down).
        weakref.finalize(self, _close_renderers, self._renderers)
        self.mask_source_used = self._resolve_mask_source(mask_source, geom_type or shapes[0])
        self.geom_type: str | None = None  # set by reset
        self.params: ObjectParams | None = None
        self._warned_clip = False
        self.perturbed = config.perturb.active()  # docs/robustness.md; nothing is drawn without them
        self.perturbation: dict | None = None  # this episode's record (mjx_push.perturb.draw_episode)

    # --- public API ----------------------------------------------------------------------------------
    def reset(
        self,
        seed: int | None = None,
        params: ObjectParams | None = None,
        geom_type: str | None = None,
        perturbation: dict | None = None,
    ) -> dict:
        """Start an episode. `seed` reseeds the environment's generator (shape draw, object draw,
        observation noise); `params` (an `ObjectParams`, JAX or NumPy leaves) fixes the object; `geom_type`
        its shape (defaults to the fixed shape, else drawn). With perturbations (`config.perturb`) the
        episode's record is drawn, or `perturbation` (a `mjx_push.perturb.draw_episode` record) used;
        their draws come from a generator spawned off the environment's, whose own stream (and so the
        observation noise) they leave as it was."""
        if perturbation is not None and not self.perturbed:
            raise ConfigError("a perturbation record needs an environment with env.perturb set")
        if seed is not None:
            self.np_random = np.random.default_rng(seed)
        shapes = self.config.objects.shapes()
        geom_type = geom_type or self.fixed_geom_type
        if geom_type is None:
            geom_type = shapes[int(self.np_random.integers(len(shapes)))] if params is None else None
        if geom_type is None:
            raise ConfigError("geom_type is required with params when the environment's shape is not fixed")
        if geom_type not in scene.SHAPES:
            raise ConfigError(f"geom_type must be one of {scene.SHAPES}, got {geom_type!r}")
        if params is None:
            params = sample_params(int(self.np_random.integers(2**31 - 1)), self.config.objects, geom_type)
        else:
            params = params_to_numpy(params)
        sim = self._sim(geom_type)
        m, d, ids = sim.model, sim.data, sim.ids
        if self.perturbed:
            self._perturb_rng = self.np_random.spawn(1)[0]
            if perturbation is None:
                perturbation = perturb.draw_episode(self.config.perturb, self._perturb_rng.random(perturb.N_UNIFORMS))
            self.perturbation = {k: np.asarray(v, np.float64) for k, v in perturbation.items()}
            params = perturb.scale_object(params, self.perturbation)
            apply_perturbation(m, sim, self.perturbation)
        self.geom_type, self.params, self._s = geom_type, params, sim
        apply_params(m, d, params, ids, geom_type)
        mujoco.mj_resetData(m, d)
        a = ids.object_qpos
        d.qpos[:7] = scene.HOME_QPOS
        d.qpos[a : a + 7] = self._object_qpos(params.start)
        mujoco.mj_forward(m, d)
        self._qpos0 = d.qpos.copy()
        self.goal_mask = self._camera_mask(self._mask(self._object_qpos(params.goal), d.qpos))
        self.target = self.home_flange.copy()
        self._prev_target, self._shown_mask = self.target, None
        self.step_count = 0
        self.corrections = corr.Corrections()
        self.episode_invalid = False
        self.invalid_count = 0
        self.bad_actions = 0
        self._last = {"substeps": 0, "max_tilt": 0.0, "max_height_error": 0.0, "invalid": False}
        return self._observation()

    def step(self, action) -> tuple[dict, float, bool, bool, dict]:
        """One environment step: `action` (3,) = (a_x, a_y, a_s) in [-1, 1]. Non-finite components become 0
        and are counted in info["bad_actions"]; values outside [-1, 1] are clipped (with a warning, once
        per environment); a wrong shape raises ValueError. Returns (obs, reward, terminated=False, truncated, info)."""
        if self.params is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (3,):
            raise ConfigError(f"action must have shape (3,) = (a_x, a_y, a_s), got {action.shape}")
        if not self._warned_clip and np.any(np.abs(action[np.isfinite(action)]) > 1.0 + 1e-6):
            # Clipping silently hid a common mistake: a decoded substep count (NumpyPolicy.act) passed as a_s.
            self._warned_clip = True
            warnings.warn(
                f"action {action.tolist()} lies outside [-1, 1] and is clipped (warned once per "
                "environment); a_s is the raw action in [-1, 1], not a substep count: pass "
                "NumpyPolicy.act_raw's output, not act's",
                UserWarning,
                stacklevel=2,
            )
        action, bad = sanitize_action(action)
        self.bad_actions += int(bad)
        cfg = self.config
        d, ids = self._s.data, self._s.ids
        self.target = flange_target(
            d.site_xpos[ids.flange_site][:2],
            action[:2],
            cfg.action_scale,
            cfg.workspace_x,
            cfg.workspace_y,
            self.home_flange[2],
        )
        n = decode_substeps(action[2], cfg.substeps)
        unstable0 = self._unstable_count()
        if "latency" in self.perturbed:  # the previous command runs on for the step's first substeps
            late = min(n, int(self.perturbation["latency"]))
            new, self.target = self.target, self._prev_target
            tilt0, herr0 = self.run_substeps(late)
            self.target = self._prev_target = new
            max_tilt, max_herr = self.run_substeps(n - late)
            max_tilt, max_herr = max(tilt0, max_tilt), max(herr0, max_herr)
        else:
            max_tilt, max_herr = self.run_substeps(n)
        # C MuJoCo resets MjData to the model's default pose by itself when qpos, qvel or qacc go bad
        # (with a warning): that is an invalid state too, though everything is finite again.
        invalid = self._unstable_count() > unstable0 or not self._valid()
        if invalid:
            self._restore_initial()
        self.episode_invalid |= invalid
        self.invalid_count += int(invalid)
        self.step_count += 1
        self._last = {"substeps": n, "max_tilt": max_tilt, "max_height_error": max_herr, "invalid": invalid}
        obs = self._observation()
        info = self.info()
        reward = float(info["success"]) - 1.0
        truncated = self.step_count >= cfg.episode_length
        return obs, reward, False, truncated, info

    def run_substeps(self, n: int) -> tuple[float, float]:
        """Run `n` 1 ms substeps towards `self.target` with the controller, counting corrections. Returns
        the largest rod tilt (rad) and flange height error (m) seen. Used by `step` and by the simulated
        robot of `mjx_push.export.deploy`."""
        cfg = self.config
        m, d, ids = self._s.model, self._s.data, self._s.ids
        ccfg = cfg.controller
        held = ctl.joint_velocity(m, d, self.target, ids, ccfg) if ccfg.hold_per_step else None
        goal_xy = self.params.goal[:2]
        home_z = self.home_flange[2]
        a = ids.object_qpos
        c = self.corrections
        max_tilt = max_herr = 0.0
        servo = bool(self.perturbed & {"velocity_gain", "velocity_lag"})
        for _ in range(int(n)):
            dq = held if held is not None else ctl.joint_velocity(m, d, self.target, ids, ccfg)
            d.ctrl[:7] = perturb.actuate(dq, d.ctrl[:7], self.perturbation) if servo else dq
            mujoco.mj_step(m, d)
            c = corr.update(c, math.hypot(d.qpos[a] - goal_xy[0], d.qpos[a + 1] - goal_xy[1]), cfg.success_tau)
            p, z = ctl.flange_pose(d, ids)
            max_tilt = max(max_tilt, ctl.rod_tilt(z))
            max_herr = max(max_herr, abs(p[2] - home_z))
        self.corrections = c
        return max_tilt, max_herr

    def info(self) -> dict:
        """Ground truth and counters (noise-free), as the MJX environment's info."""
        d, a = self._s.data, self._s.ids.object_qpos
        object_xy = d.qpos[a : a + 2].copy()
        goal_xy = self.params.goal[:2].copy()
        dist = float(np.linalg.norm(object_xy - goal_xy))
        return {
            "object_xy": object_xy,
            "object_yaw": quat_yaw(d.qpos[a + 3 : a + 7]),
            "object_z": float(d.qpos[a + 2]),
            "goal_xy": goal_xy,
            "goal_yaw": float(self.params.goal[2]),
            "ee_xy_true": d.site_xpos[self._s.ids.flange_site][:2].copy(),
            "target": self.target.copy(),
            "distance": dist,
            "success": task_rules.reached(dist, self.config.success_tau),
            "corrections": self.corrections,
            "substeps": self._last["substeps"],
            "max_tilt": self._last["max_tilt"],
            "max_height_error": self._last["max_height_error"],
            "invalid": self._last["invalid"],
            "episode_invalid": self.episode_invalid,
            "invalid_count": self.invalid_count,
            "bad_actions": self.bad_actions,
            "step": self.step_count,
            "geom_type": self.geom_type,
        }

    def flange_pos(self) -> np.ndarray:
        """True flange position (3,) (no observation noise)."""
        return self._s.data.site_xpos[self._s.ids.flange_site].copy()

    def object_mask(self) -> np.ndarray:
        """The current object mask (64, 64) bool from `mask_source_used`."""
        d, a = self._s.data, self._s.ids.object_qpos
        return self._mask(d.qpos[a : a + 7], d.qpos)

    def render_rgb(self, camera: str = "top", size: tuple[int, int] = MAX_RENDER_SIZE) -> np.ndarray:
        """RGB frame (H, W, 3) uint8 of the current state from `camera` ("top" or "under_table"), for videos
        and for the simulated camera of `mjx_push.export.deploy`. `size` = (height, width) <= (480, 640)."""
        if camera not in CAMERAS:
            raise ConfigError(f"camera must be one of {CAMERAS}, got {camera!r}")
        h, w = (int(v) for v in size)
        if not (1 <= h <= MAX_RENDER_SIZE[0] and 1 <= w <= MAX_RENDER_SIZE[1]):
            raise ConfigError(f"size must be (height, width) within {MAX_RENDER_SIZE}, got {size!r}")
        if self.params is None:
            raise RuntimeError("call reset() before render_rgb()")
        return self._render(self._s.data.qpos, camera, h, w)

    def close(self) -> None:
        _close_renderers(self._renderers)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --- internals -----------------------------------------------------------------------------------
    def _sim(self, geom_type: str) -> _ShapeSim:
        if geom_type not in self._sims:
            m = scene.build_model(geom_type, self.config.solver)
            ids = scene.scene_ids(m)
            self._sims[geom_type] = _ShapeSim(m, mujoco.MjData(m), mujoco.MjData(m), ids, _nominal(m, ids))
        return self._sims[geom_type]

    def _resolve_mask_source(self, source: str, probe_shape: str) -> str:
        if source == "analytic":
            return "analytic"
        try:
            self._renderer(probe_shape, scene.IMAGE_SIZE, scene.IMAGE_SIZE)
        except Exception as e:  # no OpenGL context (no EGL/OSMesa/display)
            if source == "render":
                raise RuntimeError(
                    f"mask_source='render' needs {unavailable_reason()}; or pass "
                    "mask_source='analytic' (the masks MJX trains with)"
                ) from e
            warnings.warn(
                f"mask_source='auto': {unavailable_reason()}; using analytic masks instead of the rendered camera",
                RuntimeWarning,
                stacklevel=3,
            )
            return "analytic"
        return "render"

    def _renderer(self, geom_type: str, h: int, w: int) -> mujoco.Renderer:
        key = (geom_type, h, w)
        if key not in self._renderers:
            self._renderers[key] = _new_renderer(self._sim(geom_type).model, h, w)
        return self._renderers[key]

    def _object_qpos(self, pose: np.ndarray) -> np.ndarray:
        z = scene.TABLE_TOP + half_height(self.params, self.geom_type)
        return np.concatenate([pose[:2], [z], yaw_quat(float(pose[2]))])

    def _mask(self, obj_qpos: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        """Mask of the object at `obj_qpos` (7,), the rest of the scene at `qpos` (seen by the episode's
        displaced camera, if any; rendered: the model's camera is moved at reset)."""
        if self.mask_source_used == "analytic":
            # Like the MJX environment: upright object at the pose's xy, yaw and centre height.
            xy, yaw = obj_qpos[:2], quat_yaw(obj_qpos[3:7])
            if self.perturbed & {"camera_shift", "camera_yaw"}:
                xy, yaw = perturb.camera_view(xy, yaw, self.perturbation["camera"])
            return mask_geometry.object_mask(self.geom_type, self.params.size, xy, yaw, obj_qpos[2])
        a = self._s.ids.object_qpos
        q = np.array(qpos, copy=True)
        q[a : a + 7] = obj_qpos
        n = scene.IMAGE_SIZE
        return render_filter(self._render(q, "under_table", n, n))

    def _render(self, qpos: np.ndarray, camera: str, h: int, w: int) -> np.ndarray:
        # Render from a scratch copy so the simulation's MjData (whose kinematics the controller reads)
        # is never recomputed by a render.
        m, v = self._s.model, self._s.scratch
        v.qpos[:] = qpos
        mujoco.mj_kinematics(m, v)
        mujoco.mj_camlight(m, v)
        r = self._renderer(self.geom_type, h, w)
        r.update_scene(v, camera=camera)
        return r.render().copy()

    def _camera_mask(self, mask: np.ndarray) -> np.ndarray:
        """The real pipeline's errors on a mask (edge, flips, opening and closing), when configured."""
        cfg = self.config.perturb
        k_max, r_max = math.ceil(abs(cfg.mask_edge)), cfg.mask_open_close
        if not (k_max or r_max or "mask_flip" in self.perturbed):
            return mask
        u_edge = self._perturb_rng.random()
        u_pix = self._perturb_rng.random(mask.shape) if "mask_flip" in self.perturbed else None
        return perturb.camera_mask(mask, self.perturbation, u_edge, u_pix, k_max, r_max)

    def _observation(self) -> dict:
        d, ids = self._s.data, self._s.ids
        ee = d.site_xpos[ids.flange_site][:2].copy()
        noise = self.config.obs_noise * self.np_random.standard_normal(2)
        if "flange_noise" in self.perturbed:
            noise = noise + self.perturbation["flange_noise"] * self._perturb_rng.standard_normal(2)
        mask = self._camera_mask(self.object_mask())
        if self.perturbed & {"frame_repeat", "frame_empty"}:
            if self._shown_mask is not None:  # the reset's frame is never missed
                mask = perturb.missed_frame(mask, self._shown_mask, self.perturbation, self._perturb_rng.random())
            self._shown_mask = mask
        return {"ee_xy": ee + noise, "object_mask": mask, "goal_mask": self.goal_mask.copy()}

    def _valid(self) -> bool:
        """As `PushEnv._valid`: finite state, object centre over the table footprint, within its height band."""
        d, a = self._s.data, self._s.ids.object_qpos
        if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
            return False
        rest = scene.TABLE_TOP + half_height(self.params, self.geom_type)
        return bool(self.config.object_in_bounds(*d.qpos[a : a + 3], rest))

    def _unstable_count(self) -> int:
        w = self._s.data.warning
        return sum(int(w[k].number) for k in _UNSTABLE_WARNINGS)

    def _restore_initial(self) -> None:
        """The episode's initial state (as the MJX environment swaps in its initial data)."""
        m, d = self._s.model, self._s.data
        mujoco.mj_resetData(m, d)
        d.qpos[:] = self._qpos0
        mujoco.mj_forward(m, d)

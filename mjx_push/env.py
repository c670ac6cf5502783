"""The pushing task as a functional MJX environment with brax's `Env` interface (docs/task.md sections 1-4, 8).

One `PushEnv` simulates one environment with an object of one geom type; use it batched with
`jax.vmap` (or through `mjx_push.batch.PushBatch`, which also mixes shapes). Everything an episode needs
lives in the `State` pytree, so `reset` and `step` are pure and jittable. For brax's trainers and
training wrappers use `mjx_push.brax_env.BraxPushEnv`, which wraps it (flat observations, the wrappers'
time limits and auto-resets).

An environment step is split in three so that a scheduler can interleave environments whose a_s
differ (see `mjx_push.batch` for the utilisation this costs when they wait for each other):
`begin_step` (decode the action, set the target and the substep budget) -> `advance` (run up to n
substeps; an environment whose budget is spent stands still) -> `finish_step` (observation, reward,
validity). `step` chains them with an unbounded `advance`.

Perturbations of a real cell (`config.perturb`, `mjx_push.perturb`; off by default, and then none of
their code runs): the record drawn at reset (or given to `reset_with`) scales the object's mass and
friction, changes the rod's geometry and displaces the camera; observations pass through the real
pipeline's mask errors and a missed frame; the first substeps of a step run the previous target
(latency), and every substep the servo's gain and lag.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs.base import Env, State
from mujoco import mjx

from mjx_push import controller as ctl
from mjx_push import corrections as corr
from mjx_push import masks, objects, perturb, scene, task_rules
from mjx_push.config import EnvConfig  # the task settings, without JAX (also imported from here)
from mjx_push.errors import ConfigError


_PERTURB_STREAM = 0x7E57  # folded into the reset key for the episode's perturbation record


# Explicit dtypes everywhere in the state: a weakly typed scalar returned by reset but strongly typed
# after a step would make every jitted caller compile twice.
def _f0() -> jax.Array:
    """A float zero of JAX's default float type (float32; float64 under jax_enable_x64)."""
    return jnp.zeros((), jnp.result_type(float))


# The step's rules (`mjx_push.task_rules`, shared with the CPU environment) evaluated with jax.numpy.
def decode_substeps(a_s: jax.Array, substeps: tuple[int, int]) -> jax.Array:
    """a_s in [-1, 1] -> integer substeps in [low, high] (linear, truncated), int32."""
    return task_rules.decode_substeps(a_s, substeps, xp=jnp)


def sanitize_action(action: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Documented clip: non-finite components become 0 and the rest are clipped to [-1, 1].
    Returns the action and whether anything was non-finite (counted in info['bad_actions'])."""
    return task_rules.sanitize_action(action, xp=jnp)


# The fields MuJoCo's kinematics and centre-of-mass passes write (mj_kinematics, mj_comPos).
_KINEMATIC_FIELDS = ("xpos", "xquat", "xmat", "xipos", "ximat", "xanchor", "xaxis")
_KINEMATIC_FIELDS += ("geom_xpos", "geom_xmat", "site_xpos", "site_xmat", "subtree_com", "cdof")


def data_at_home(mj_model: mujoco.MjModel, data: mjx.Data) -> mjx.Data:
    """`data` with the arm at its home pose and the kinematics of that pose, computed once on the host.

    Every episode starts with the arm at home; only the object's pose differs, and nothing reads the
    object's kinematics before the first substep's forward pass recomputes everything from qpos and
    qvel. So a reset needs no forward pass of its own (which would compile a second copy of the
    kinematics, collision and the solver into every rollout), only the flange's pose and Jacobian
    that the controller and the first observation read."""
    d = mujoco.MjData(mj_model)
    d.qpos[: len(scene.HOME_QPOS)] = scene.HOME_QPOS
    mujoco.mj_kinematics(mj_model, d)
    mujoco.mj_comPos(mj_model, d)
    like = lambda target, x: jnp.asarray(x, data.qpos.dtype).reshape(target.shape)  # noqa: E731
    data = data.replace(**{f: like(getattr(data, f), getattr(d, f)) for f in _KINEMATIC_FIELDS})
    return data.tree_replace({"_impl.cinert": like(data._impl.cinert, d.cinert)})


def yaw_quat(yaw: jax.Array) -> jax.Array:
    return task_rules.yaw_quat(yaw, xp=jnp)


def quat_yaw(q: jax.Array) -> jax.Array:
    return task_rules.quat_yaw(q, xp=jnp)


class PushEnv(Env):
    """Franka Panda pushes one object of geom type `geom_type` ("box" or "cylinder") to a goal."""

    def __init__(self, config: EnvConfig = EnvConfig(), geom_type: str = "box"):
        if geom_type not in config.objects.shapes():
            raise ConfigError(
                f"geom_type {geom_type!r} is not drawn by shape filter {config.objects.shape!r}"
                f" (it draws {config.objects.shapes()})"
            )
        self.config = config
        self.geom_type = geom_type
        self.mj_model = scene.build_model(geom_type, config.solver)
        self.ids = scene.scene_ids(self.mj_model)
        self.sys = mjx.put_model(self.mj_model)
        self._home_data = data_at_home(self.mj_model, mjx.make_data(self.sys))
        self.home_flange = self._home_data.site_xpos[self.ids.flange_site]  # scene.home_flange_pos()
        # The perturbations this environment runs (docs/robustness.md): a static set, so an environment
        # without any runs exactly the code it always ran.
        self.perturbed = config.perturb.active()
        self._edge_max = int(np.ceil(abs(config.perturb.mask_edge)))
        self._flips = "mask_flip" in self.perturbed

    # --- brax Env interface -------------------------------------------------------------------------
    @property
    def observation_size(self):
        n = scene.IMAGE_SIZE
        return {"ee_xy": (2,), "object_mask": (n, n), "goal_mask": (n, n)}

    @property
    def action_size(self) -> int:
        return 3

    @property
    def backend(self) -> str:
        return "mjx"

    def reset(self, rng: jax.Array) -> State:
        rng, k_obj = jax.random.split(rng)
        params = objects.sample(k_obj, self.config.objects, self.geom_type, self.home_flange[:2])
        return self.reset_with(rng, params)

    def draw_perturbation(self, rng: jax.Array) -> dict:
        """The perturbation record (`mjx_push.perturb.draw_episode`) `reset_with(rng, params)` draws."""
        u = jax.random.uniform(jax.random.fold_in(rng, _PERTURB_STREAM), (perturb.N_UNIFORMS,))
        return perturb.draw_episode(self.config.perturb, u, xp=jnp)

    def reset_with(self, rng: jax.Array, params: objects.ObjectParams, perturbation: dict | None = None) -> State:
        """Start an episode with the given object (evaluation scenarios, tests, replays). An environment
        with perturbations (`config.perturb`) draws the episode's record from `rng`, or takes
        `perturbation` (a `mjx_push.perturb.draw_episode` record: the stress suite, tests); the object's
        mass and friction factors apply to `params` here."""
        if perturbation is not None and not self.perturbed:
            raise ConfigError("a perturbation record needs an environment with env.perturb set")
        rng0 = rng
        rng, k_noise = jax.random.split(rng)
        if self.perturbed:
            if perturbation is None:
                perturbation = self.draw_perturbation(rng0)
            perturbation = jax.tree.map(lambda x: jnp.asarray(x, jnp.result_type(float)), perturbation)
            params = perturb.scale_object(params, perturbation, xp=jnp)
        data = self._initial_data(params)
        hh = objects.half_height(params, self.geom_type)
        goal_mask = self._mask(
            params, params.goal[:2], params.goal[2], scene.TABLE_TOP + hh, perturbation, jax.random.fold_in(rng0, 1)
        )
        zero_i = jnp.asarray(0, jnp.int32)
        info = {
            "rng": rng,
            "params": params,
            "initial_data": data,
            "goal_mask": goal_mask,
            "step": zero_i,
            "target": self.home_flange,
            "substeps_left": zero_i,
            "substeps": zero_i,  # substeps run by the last env step
            "held_ctrl": jnp.zeros(7),
            "corrections": corr.Corrections.init(),
            "episode_invalid": jnp.asarray(False),
            "invalid_count": zero_i,
            "bad_actions": zero_i,
            "max_tilt": _f0(),
            "max_height_error": _f0(),
            "truncation": _f0(),
        }
        if self.perturbed:
            info["perturbation"] = perturbation
            if "latency" in self.perturbed:  # the command before the step's own (home at reset)
                info.update(prev_target=self.home_flange, prev_held=jnp.zeros(7))
        info.update(self._ground_truth(data, params))
        obs = self._observation(data, info, k_noise)
        if "frame_repeat" in self.perturbed:
            info["shown_mask"] = obs["object_mask"]
        reward, success = self._reward(info)
        metrics = {"success": success}
        return State(data, obs, reward, _f0(), metrics, info)

    def step(self, state: State, action: jax.Array) -> State:
        if "first_pipeline_state" in state.info:  # a static check: info's keys are fixed when tracing
            raise ConfigError(
                "PushEnv under brax's AutoResetWrapper would replay one object and end an episode "
                "at every step (its episodes live in info, which the wrapper does not reset): "
                "give brax's trainers mjx_push.brax_env.BraxPushEnv instead"
            )
        return self.finish_step(self.advance(self.begin_step(state, action)))

    # --- the three phases of a step ------------------------------------------------------------------
    def begin_step(self, state: State, action: jax.Array) -> State:
        action = jnp.asarray(action)
        if action.shape != (3,):
            raise ConfigError(f"action must have shape (3,) = (a_x, a_y, a_s) per environment, got {action.shape}")
        action, bad = sanitize_action(action)
        cfg = self.config
        ee = state.pipeline_state.site_xpos[self.ids.flange_site]
        target = task_rules.flange_target(
            ee, action[:2], cfg.action_scale, cfg.workspace_x, cfg.workspace_y, self.home_flange[2], xp=jnp
        )
        n = decode_substeps(action[2], cfg.substeps)
        info = dict(state.info)
        if "latency" in self.perturbed:
            info.update(prev_target=info["target"], prev_held=info["held_ctrl"])
        info.update(target=target, substeps_left=n, substeps=n, bad_actions=info["bad_actions"] + bad)
        info.update(max_tilt=_f0(), max_height_error=_f0())
        if cfg.controller.hold_per_step:
            m = self._model(info["params"], info.get("perturbation"))
            info["held_ctrl"] = ctl.joint_velocity(m, state.pipeline_state, target, self.ids, cfg.controller)
        return state.replace(info=info)

    def advance(self, state: State, max_substeps: int | None = None) -> State:
        """Run up to `max_substeps` substeps (all remaining if None) of the current env step.

        With `max_substeps` the chunk is a loop of exactly that many iterations (a `scan`, whose trip
        count XLA knows at compile time), spent substeps masked: a GPU runs it without copying a loop
        predicate to the host each substep. Under `vmap` this is what a `while_loop` with a batched
        predicate computes too (every iteration runs for all and selects), so the results are the
        same up to the order of float operations. Without it (one environment's whole step) a
        `while_loop` stops at the last substep."""
        m = self._model(state.info["params"], state.info.get("perturbation"))
        cfg = self.config
        goal_xy = state.info["params"].goal[:2]
        home_z = self.home_flange[2]
        latency = "latency" in self.perturbed
        servo = bool(self.perturbed & {"velocity_gain", "velocity_lag"})

        def substep(carry):
            data, info = carry
            target, held = info["target"], info["held_ctrl"]
            if latency:  # the previous command runs on for the step's first substeps
                late = info["substeps"] - info["substeps_left"] < info["perturbation"]["latency"]
                target = jnp.where(late, info["prev_target"], target)
                held = jnp.where(late, info["prev_held"], held)
            if cfg.controller.hold_per_step:
                dq = held
            else:
                dq = ctl.joint_velocity(m, data, target, self.ids, cfg.controller)
            if servo:
                dq = perturb.actuate(dq, data.ctrl, info["perturbation"], xp=jnp)
            data = mjx.step(m, data.replace(ctrl=dq))
            # Metrics on the substep's kinematics (MJX data after a step holds the positions the step
            # started from; one substep of lag is immaterial for counting).
            obj_xy = data.qpos[self.ids.object_qpos : self.ids.object_qpos + 2]
            c = corr.update(info["corrections"], jnp.linalg.norm(obj_xy - goal_xy), cfg.success_tau)
            p, z = ctl.flange_pose(data, self.ids)
            info = dict(info)
            info.update(
                corrections=c,
                substeps_left=info["substeps_left"] - 1,
                max_tilt=jnp.maximum(info["max_tilt"], ctl.rod_tilt(z)),
                max_height_error=jnp.maximum(info["max_height_error"], jnp.abs(p[2] - home_z)),
            )
            return data, info

        carry0 = (state.pipeline_state, dict(state.info))
        if max_substeps is None:
            data, info = jax.lax.while_loop(lambda c: c[1]["substeps_left"] > 0, substep, carry0)
        else:

            def masked(carry, _):
                new = substep(carry)
                active = carry[1]["substeps_left"] > 0
                return jax.tree.map(lambda a, b: jnp.where(active, a, b), new, carry), None

            (data, info), _ = jax.lax.scan(masked, carry0, None, length=max_substeps)
        return state.replace(pipeline_state=data, info=info)

    def finish_step(self, state: State) -> State:
        info = dict(state.info)
        params = info["params"]
        data = state.pipeline_state
        rng, k_noise = jax.random.split(info["rng"])
        invalid = ~self._valid(data, params)
        # An invalid state (NaN, object through or off the table) is replaced by the episode's initial
        # state (kept from reset: no second forward pass to compile) so nothing non-finite reaches the
        # learner; the episode stays flagged until reset.
        data = jax.tree.map(lambda a, b: jnp.where(invalid, a, b), info["initial_data"], data)
        info.update(self._ground_truth(data, params))
        info["rng"] = rng
        info["step"] = info["step"] + 1
        info["episode_invalid"] = info["episode_invalid"] | invalid
        info["invalid_count"] = info["invalid_count"] + invalid.astype(jnp.int32)
        done = (info["step"] >= self.config.episode_length).astype(jnp.result_type(float))
        info["truncation"] = done  # time limit only: learners bootstrap
        obs = self._observation(data, info, k_noise)
        if self.perturbed & {"frame_repeat", "frame_empty"}:  # a missed frame
            u = jax.random.uniform(jax.random.fold_in(k_noise, 3), ())
            shown = info.get("shown_mask", obs["object_mask"])
            mask = perturb.missed_frame(obs["object_mask"], shown, info["perturbation"], u, xp=jnp)
            obs = dict(obs, object_mask=mask)
            if "shown_mask" in info:
                info["shown_mask"] = mask
        reward, success = self._reward(info)
        metrics = dict(state.metrics)
        metrics["success"] = success
        return state.replace(pipeline_state=data, obs=obs, reward=reward, done=done, metrics=metrics, info=info)

    # --- helpers -------------------------------------------------------------------------------------
    def model(self, params: objects.ObjectParams) -> mjx.Model:
        """The MJX model of an environment with object `params`."""
        return objects.apply(self.sys, params, self.ids, self.geom_type)

    def _model(self, params: objects.ObjectParams, perturbation: dict | None) -> mjx.Model:
        """`model(params)` with the push rod of the episode's perturbation record."""
        m = self.model(params)
        if not self.perturbed & {"rod_radius", "rod_length"}:
            return m
        g, mj = self.ids.rod_geom, self.mj_model
        size, pos, rbound, aabb = perturb.rod_geometry(
            mj.geom_size[g], mj.geom_pos[g], mj.geom_rbound[g], mj.geom_aabb[g], perturbation["rod"], xp=jnp
        )
        return m.tree_replace(
            {
                "geom_size": m.geom_size.at[g].set(size),
                "geom_pos": m.geom_pos.at[g].set(pos),
                "geom_rbound": m.geom_rbound.at[g].set(rbound),
                "geom_aabb": m.geom_aabb.at[g].set(aabb),
            }
        )

    def _initial_data(self, params: objects.ObjectParams) -> mjx.Data:
        hh = objects.half_height(params, self.geom_type)
        obj = jnp.concatenate([params.start[:2], (scene.TABLE_TOP + hh)[None], yaw_quat(params.start[2])])
        qpos = jnp.concatenate([jnp.asarray(scene.HOME_QPOS, jnp.result_type(float)), obj])
        return self._home_data.replace(qpos=qpos)  # the arm's kinematics at home (`data_at_home`)

    def _ground_truth(self, data: mjx.Data, params: objects.ObjectParams) -> dict:
        a, v = self.ids.object_qpos, self.ids.object_qvel
        # Flange velocity from the Jacobian (once per env step; the substep loop never needs it).
        p = data.site_xpos[self.ids.flange_site]
        jacp, _ = mjx.jac(self.model(params), data, p, self.ids.link7_body)
        return {
            "object_xy": data.qpos[a : a + 2],
            "object_yaw": quat_yaw(data.qpos[a + 3 : a + 7]),
            "object_z": data.qpos[a + 2],
            # Planar velocity of the object: vx, vy (world) and the yaw rate.
            "object_vel": jnp.stack([data.qvel[v], data.qvel[v + 1], data.qvel[v + 5]]),
            "goal_xy": params.goal[:2],
            "goal_yaw": params.goal[2],
            "ee_xy_true": p[:2],
            "ee_vel": (jacp.T @ data.qvel)[:2],
        }

    def _mask(self, params, xy, yaw, z_center, perturbation: dict | None, key) -> jax.Array:
        """The camera's mask of the object at (xy, yaw): the analytic silhouette, seen by the episode's
        displaced camera and through the real pipeline's errors when the environment has them."""
        p = self.perturbed
        if "camera_shift" in p or "camera_yaw" in p:
            xy, yaw = perturb.camera_view(xy, yaw, perturbation["camera"], xp=jnp)
        mask = masks.object_mask(self.geom_type, params.size, xy, yaw, z_center)
        r_max = self.config.perturb.mask_open_close
        if self._edge_max or self._flips or r_max:
            k_edge, k_pix = jax.random.split(key)
            u_pix = jax.random.uniform(k_pix, mask.shape) if self._flips else None
            u_edge = jax.random.uniform(k_edge, ())
            mask = perturb.camera_mask(mask, perturbation, u_edge, u_pix, self._edge_max, r_max, xp=jnp)
        return mask

    def _observation(self, data, info, key) -> dict:
        a = self.ids.object_qpos
        params = info["params"]
        yaw = quat_yaw(data.qpos[a + 3 : a + 7])
        # Perturbation draws come from streams folded off the noise key: the noise itself is unchanged.
        obj_mask = self._mask(
            params, data.qpos[a : a + 2], yaw, data.qpos[a + 2], info.get("perturbation"), jax.random.fold_in(key, 1)
        )
        ee = data.site_xpos[self.ids.flange_site][:2]
        noise = self.config.obs_noise * jax.random.normal(key, (2,))
        if "flange_noise" in self.perturbed:
            noise = noise + info["perturbation"]["flange_noise"] * jax.random.normal(jax.random.fold_in(key, 2), (2,))
        return {"ee_xy": ee + noise, "object_mask": obj_mask, "goal_mask": info["goal_mask"]}

    def _reward(self, info) -> tuple[jax.Array, jax.Array]:
        dist = jnp.linalg.norm(info["object_xy"] - info["goal_xy"])
        success = task_rules.reached(dist, self.config.success_tau).astype(jnp.result_type(float))
        return success - 1.0, success

    def _valid(self, data: mjx.Data, params: objects.ObjectParams) -> jax.Array:
        a = self.ids.object_qpos
        finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        rest = scene.TABLE_TOP + objects.half_height(params, self.geom_type)
        return finite & self.config.object_in_bounds(data.qpos[a], data.qpos[a + 1], data.qpos[a + 2], rest)

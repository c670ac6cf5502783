"""CPU MuJoCo environment (mjx_push.export.cpu_env) against the MJX environment (its Gymnasium wrapper: test_gym_env.py).

JAX use is kept to the session fixture `box_sim` (one compiled reset and step, shared with the physics
tests) and a few small eager or jitted calls."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from mjx_push.export import controller_np, corrections_np
from mjx_push.export.cpu_env import CpuPushEnv, decode_substeps, renderer_available, sanitize_action
from mjx_push import controller, mask_geometry, masks, objects, scene
from mjx_push import corrections as corr
from mjx_push import env as mjx_env
from tests.helpers import B, HOME_XY, a_s_for, make_params, renderer_or_skip

N_MASK_POSES = 40  # per shape


def _np_params(p):
    return jax.tree.map(np.asarray, p)


@pytest.fixture(scope="module")
def box_env():
    return CpuPushEnv(geom_type="box", mask_source="analytic", seed=0)


# --- physics and controller against MJX ---------------------------------------------------------------
def test_flange_trajectory_matches_mjx(box_sim):
    """Identical actions, no contact (object behind the arm): CPU MuJoCo follows MJX within 1 mm."""
    params = [make_params("box", start=(-0.12, -0.1, 0.3))] * B
    rng = np.random.default_rng(0)
    steps = 12
    acts = np.stack(
        [
            rng.uniform(-0.04, 0.08, (steps, B)),
            rng.uniform(-0.08, 0.08, (steps, B)),
            rng.uniform(-1.0, 0.0, (steps, B)),
        ],
        axis=-1,
    ).astype(np.float32)
    acts[3, 0, :2] = (0.6, 0.0)  # one target clipped to the workspace edge (x 0.65), crossing open space
    state = box_sim.start(params)
    ee_mjx, n_mjx, obj_mjx = [np.asarray(state.info["ee_xy_true"])], [], []
    for k in range(steps):
        state = box_sim.step(state, jnp.asarray(acts[k]))
        ee_mjx.append(np.asarray(state.info["ee_xy_true"]))
        n_mjx.append(np.asarray(state.info["substeps"]))
        obj_mjx.append(np.asarray(state.info["object_xy"]))
    ee_mjx, n_mjx, obj_mjx = np.stack(ee_mjx), np.stack(n_mjx), np.stack(obj_mjx)

    env = CpuPushEnv(geom_type="box", mask_source="analytic")
    worst = 0.0
    for b in range(B):
        env.reset(params=_np_params(params[b]))
        ee = [env.info()["ee_xy_true"]]
        for k in range(steps):
            _, _, terminated, truncated, info = env.step(acts[k, b])
            assert info["substeps"] == n_mjx[k, b]
            assert not terminated and not truncated and not info["invalid"]
            ee.append(info["ee_xy_true"])
        err = np.abs(np.stack(ee) - ee_mjx[:, b]).max()
        worst = max(worst, err)
        np.testing.assert_allclose(info["object_xy"], obj_mjx[-1, b], atol=2e-4)  # resting object, both sims
    assert worst < 1e-3, f"flange differs from MJX by {worst * 1e3:.3f} mm"


@pytest.mark.parametrize("tilt_law", ["axis", "dot"])
def test_controller_port_matches_jax(tilt_law):
    """The NumPy law equals mjx_push.controller.joint_velocity on the same state, with joints near their
    limits so the clipping is exercised."""
    m = scene.build_model("box")
    d = mujoco.MjData(m)
    ids = scene.scene_ids(m)
    q = scene.HOME_QPOS + np.random.default_rng(1).normal(0, 0.05, 7)
    q[5] = scene.JOINT_RANGE[5, 1] - 0.01  # 1 cm short of joint 6's upper limit
    d.qpos[:7] = q
    mujoco.mj_forward(m, d)
    cfg = controller.ControllerConfig(tilt_law=tilt_law, hold_gain=3.0, damping=0.3, gain=1.2, safety_scale=0.8)
    target = scene.home_flange_pos() + np.array([0.08, -0.05, 0.01])
    ref = controller.joint_velocity(mjx.put_model(m), mjx.put_data(m, d), jnp.asarray(target, jnp.float32), ids, cfg)
    got = controller_np.joint_velocity(m, d, target, ids, cfg)
    np.testing.assert_allclose(got, np.asarray(ref), atol=1e-5)
    assert got[6] == 0.0


def test_hold_per_step_runs():
    cfg = mjx_env.EnvConfig(controller=controller.ControllerConfig(hold_per_step=True))
    env = CpuPushEnv(cfg, geom_type="box", mask_source="analytic")
    env.reset(params=_np_params(make_params("box", start=(-0.12, -0.1, 0.0))))
    x0 = env.flange_pos()[0]
    _, _, _, _, info = env.step(np.array([0.05, 0.0, a_s_for(100)]))
    assert info["substeps"] == 100 and env.flange_pos()[0] > x0 + 1e-3


def test_decode_and_sanitize_match_jax():
    a_s = np.concatenate([np.linspace(-1.2, 1.2, 97), [a_s_for(n) for n in (10, 11, 300, 599, 600)]])
    ref = np.asarray(jax.vmap(lambda a: mjx_env.decode_substeps(a, (10, 600)))(jnp.asarray(a_s, jnp.float32)))
    got = np.array([decode_substeps(np.float32(a), (10, 600)) for a in a_s])
    np.testing.assert_array_equal(got, ref)
    act, bad = sanitize_action(np.array([np.nan, 2.0, -np.inf]))
    ref_act, ref_bad = mjx_env.sanitize_action(jnp.array([np.nan, 2.0, -np.inf]))
    np.testing.assert_array_equal(act, np.asarray(ref_act))
    assert bad and bool(ref_bad)


# --- masks --------------------------------------------------------------------------------------------
def _random_objects(shape, n, rng):
    if shape == "box":
        size = np.stack([rng.uniform(0.025, 0.055, n), rng.uniform(0.025, 0.055, n), rng.uniform(0.023, 0.04, n)], -1)
        hh = size[:, 2]
    else:
        size = np.stack([rng.uniform(0.04, 0.055, n), rng.uniform(0.023, 0.0275, n), np.zeros(n)], -1)
        hh = size[:, 1]
    xy = HOME_XY + np.stack([rng.uniform(-0.25, 0.30, n), rng.uniform(-0.30, 0.30, n)], -1)
    yaw = rng.uniform(-np.pi, np.pi, n)
    return size, xy, yaw, scene.TABLE_TOP + hh


@pytest.mark.parametrize("shape", scene.SHAPES)
def test_numpy_masks_equal_jax_masks(shape):
    size, xy, yaw, z = _random_objects(shape, 64, np.random.default_rng(3))
    got = mask_geometry.object_mask(shape, size, xy, yaw, z)
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    batched = jax.jit(jax.vmap(lambda s, p, y, h: masks.object_mask(shape, s, p, y, h)))
    ref = np.asarray(batched(f(size), f(xy), f(yaw), f(z)))
    assert got.shape == ref.shape == (64, scene.IMAGE_SIZE, scene.IMAGE_SIZE)
    assert (got == ref).mean() > 0.999, f"pixel agreement {(got == ref).mean():.6f}"
    # One pose at a time gives the same as the batch.
    np.testing.assert_array_equal(mask_geometry.object_mask(shape, size[5], xy[5], yaw[5], z[5]), got[5])


def test_numpy_mask_pixel_convention():
    cx, cy = scene.CAMERA_POS[:2]
    size = np.array([0.02, 0.02, 0.02])
    centre = np.argwhere(mask_geometry.object_mask("box", size, (cx, cy), 0.0, scene.TABLE_TOP + 0.02)).mean(0)
    np.testing.assert_allclose(centre, [31.5, 31.5], atol=0.01)
    right = np.argwhere(mask_geometry.object_mask("box", size, (cx + 0.1, cy), 0.0, scene.TABLE_TOP + 0.02)).mean(0)
    assert right[1] > centre[1] + 5 and abs(right[0] - centre[0]) < 0.01


@pytest.mark.renderer
@pytest.mark.parametrize("shape", scene.SHAPES)
def test_rendered_masks_match_analytic(shape):
    """mask_source="render" (the environment's colour-filtered render) against the NumPy analytic masks."""
    renderer_or_skip()
    env = CpuPushEnv(geom_type=shape, mask_source="render")
    assert env.mask_source_used == "render"
    rng = np.random.default_rng(11 if shape == "box" else 12)
    size, xy, yaw, _ = _random_objects(shape, N_MASK_POSES, rng)
    ious = []
    base = _np_params(make_params(shape))
    for i in range(N_MASK_POSES):
        p = base.replace(size=size[i], start=np.array([xy[i, 0], xy[i, 1], yaw[i]]))
        obs = env.reset(params=p)
        info = env.info()
        ana = mask_geometry.object_mask(shape, size[i], info["object_xy"], info["object_yaw"], info["object_z"])
        ren = obs["object_mask"]
        assert ren.sum() > 10, "the renderer must see every object"
        ious.append((ana & ren).sum() / (ana | ren).sum())
    env.close()
    ious = np.array(ious)
    assert ious.mean() >= 0.95, f"mean IoU {ious.mean():.4f}"
    assert ious.min() >= 0.85, f"min IoU {ious.min():.4f}"


def test_auto_mask_source_resolves():
    env = CpuPushEnv(geom_type="cylinder", mask_source="auto")
    assert env.mask_source_used in ("render", "analytic")
    assert env.mask_source_used == ("render" if renderer_available() else "analytic")
    env.close()


# --- validity, corrections, actions -------------------------------------------------------------------
@pytest.mark.parametrize("fault", ["off_table", "sunk", "nan"])
def test_invalid_state_detected_and_replaced(box_env, fault):
    env = box_env
    obs0 = env.reset(params=_np_params(make_params("box", start=(-0.12, -0.1, 0.2))))
    xy0 = env.info()["object_xy"]
    d, a = env._s.data, env._s.ids.object_qpos
    if fault == "off_table":
        d.qpos[a] = scene.TABLE_X[1] + 0.3
    elif fault == "sunk":
        d.qpos[a + 2] = scene.TABLE_TOP - 0.05
    else:
        d.qvel[a] = np.nan
    # C MuJoCo resets the data itself on a NaN and logs a warning (to MUJOCO_LOG.TXT unless intercepted).
    seen, previous = [], mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(seen.append)
    try:
        _, _, _, _, info = env.step(np.array([0.0, 0.0, a_s_for(10)]))
    finally:
        mujoco.set_mju_user_warning(previous)
    assert bool(seen) == (fault == "nan")
    assert info["invalid"] and info["episode_invalid"] and info["invalid_count"] == 1
    np.testing.assert_allclose(info["object_xy"], xy0, atol=1e-9)  # back at the episode's initial state
    assert np.all(np.isfinite(env._s.data.qpos)) and np.all(np.isfinite(env._s.data.qvel))
    _, _, _, _, info = env.step(np.array([0.0, 0.0, a_s_for(10)]))
    assert not info["invalid"] and info["episode_invalid"] and info["invalid_count"] == 1
    assert obs0["goal_mask"].any()


def test_corrections_port_matches_jax():
    """Counter trajectories of the NumPy port equal mjx_push.corrections on scripted distance sequences."""
    rng = np.random.default_rng(5)
    pieces = [
        np.linspace(0.05, 0.005, 20),
        np.linspace(0.005, 0.021, 10),
        np.linspace(0.021, 0.004, 10),  # overshoot
        np.tile(np.concatenate([np.linspace(0.02, 0.04, 5), np.linspace(0.04, 0.02, 5)]), 3),  # oscillation
        [0.00999, 0.010005, 0.00999, 0.010005, 0.00999],  # jitter inside the dead band
        [0.0099, 0.01001, 0.0099, 0.0101, np.nan, 0.02, 0.005],
        0.01 + np.cumsum(rng.normal(0, 4e-5, 300)),  # random walk around tau
    ]
    seq = np.concatenate([np.asarray(p, np.float64) for p in pieces]).astype(np.float32)

    def body(c, d):
        c = corr.update(c, d)
        return c, (c.overshoot, c.distance, c.flag)

    _, (over, dist, flag) = jax.lax.scan(body, corr.Corrections.init(), jnp.asarray(seq))
    c = corrections_np.Corrections()
    got = []
    for d in seq:
        c = corrections_np.update(c, float(d))
        got.append((c.overshoot, c.distance, c.flag))
    got = np.array(got)
    np.testing.assert_array_equal(got[:, 0], np.asarray(over))
    np.testing.assert_array_equal(got[:, 1], np.asarray(dist))
    np.testing.assert_array_equal(got[:, 2].astype(bool), np.asarray(flag))
    assert got[-1, 0] >= 2 and got[-1, 1] >= 4  # the sequence does exercise both counters


def test_push_counts_corrections_and_rewards(box_env):
    """Drive the object through its goal: reward turns 0 at the goal and counters move."""
    env = box_env
    p = make_params("box", start=(0.1, 0.0, 0.0), goal=(0.16, 0.0, 0.0), mass=0.05)
    env.reset(params=_np_params(p))
    rewards = []
    for _ in range(6):
        ee = env.flange_pos()[:2]
        target = HOME_XY + np.array([0.25, 0.0])
        _, r, _, _, info = env.step(np.concatenate([target - ee, [a_s_for(400)]]))
        rewards.append(r)
    assert info["object_xy"][0] > HOME_XY[0] + 0.12, "the rod must have pushed the object along +x"
    assert info["corrections"].overshoot >= 1, "pushed through the goal region and out again"
    assert 0.0 in rewards and set(rewards) <= {-1.0, 0.0} and info["max_tilt"] < np.radians(2)


def test_action_handling(box_env):
    env = box_env
    params = _np_params(make_params("box", start=(-0.12, -0.1, 0.0)))
    env.reset(params=params)
    for bad_shape in (np.zeros(2), np.zeros((1, 3)), np.zeros(4)):
        with pytest.raises(ValueError, match="shape"):
            env.step(bad_shape)
    env.reset(seed=4, params=params)
    _, _, _, _, info_nan = env.step(np.array([np.nan, 0.03, 5.0]))
    ee_nan = env.flange_pos()
    env.reset(seed=4, params=params)
    _, _, _, _, info_ref = env.step(np.array([0.0, 0.03, 1.0]))
    np.testing.assert_array_equal(env.flange_pos(), ee_nan)  # NaN -> 0, 5.0 -> 1.0
    assert info_nan["bad_actions"] == 1 and info_ref["bad_actions"] == 0
    assert info_nan["substeps"] == 600


def test_episode_length_and_truncation():
    cfg = mjx_env.EnvConfig(episode_length=3, substeps=(10, 20))
    env = CpuPushEnv(cfg, geom_type="cylinder", mask_source="analytic", seed=1)
    obs = env.reset()
    assert obs["object_mask"].shape == obs["goal_mask"].shape == (64, 64) and obs["object_mask"].dtype == bool
    flags = [env.step(np.zeros(3))[3] for _ in range(3)]
    assert flags == [False, False, True]


def test_reset_draws_shapes_and_is_seeded():
    env = CpuPushEnv(mask_source="analytic")
    shapes = set()
    for s in range(8):
        env.reset(seed=s)
        shapes.add(env.geom_type)
    assert shapes == {"box", "cylinder"}
    a = env.reset(seed=3)
    pa, ga = env.params, env.geom_type
    b = env.reset(seed=3)
    assert env.geom_type == ga
    np.testing.assert_array_equal(env.params.size, pa.size)
    np.testing.assert_array_equal(a["ee_xy"], b["ee_xy"])
    with pytest.raises(ValueError, match="geom_type"):
        env.reset(params=pa)  # shape not fixed: params need a geom_type
    with pytest.raises(ValueError, match="mask_source"):
        CpuPushEnv(mask_source="camera")
    with pytest.raises(ValueError, match="geom_type"):
        CpuPushEnv(mjx_env.EnvConfig(objects=objects.ObjectConfig(shape="cylinder")), geom_type="box")

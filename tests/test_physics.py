"""Physics validity (docs/task.md section 8), the controller, exact substep counts and invalid-state handling.

All tests share one compiled reset and step per shape (batch size helpers.B)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import controller, scene
from tests.helpers import B, HOME_XY, a_s_for, action_for, make_params


def rest_params(geom_type):
    # Extremes of mass (0.5 g, 2.5 kg) and sliding friction, smallest and tallest sizes.
    combos = [(0.0005, 0.2, 0.05, 0.046), (0.0005, 1.0, 0.11, 0.08), (2.5, 0.2, 0.05, 0.046), (2.5, 1.0, 0.11, 0.08)]
    out = []
    for mass, fr, side, h in combos:
        if geom_type == "cylinder":
            out.append(
                make_params(
                    "cylinder", radius=side / 2 if side > 0.08 else 0.04, height=min(h, 0.055), mass=mass, friction=fr
                )
            )
        else:
            out.append(make_params("box", sides=(side, side), height=min(h, side), mass=mass, friction=fr))
    return out


def hold_still(state):
    ee = state.info["ee_xy_true"]
    return action_for(ee, ee, 1.0)  # zero offset, 600 substeps


@pytest.mark.parametrize("shape", ["box", "cylinder"])
def test_resting_object_stays_put(shape, box_sim, cyl_sim):
    sim = box_sim if shape == "box" else cyl_sim
    params = rest_params(shape)
    state = sim.start(params)
    xy0 = np.asarray(state.info["object_xy"])
    rest_z = scene.TABLE_TOP + np.array([p.size[2] if shape == "box" else p.size[1] for p in params])
    for _ in range(4):  # 4 x 600 substeps = 2.4 s
        state = sim.step(state, hold_still(state))
        z = np.asarray(state.info["object_z"])
        assert np.all(np.isfinite(z))
        assert np.all(np.linalg.norm(np.asarray(state.info["object_xy"]) - xy0, axis=1) < 1e-3)
        assert np.all(z > rest_z - 1e-3), f"sank: {rest_z - z}"
        assert np.all(z < rest_z + 1e-3)
    assert np.all(np.asarray(state.info["invalid_count"]) == 0)
    assert float(state.pipeline_state.time[0]) == pytest.approx(2.4, abs=1e-3)


def test_sampled_mass_and_friction_reach_the_simulation(box_sim):
    params = rest_params("box")
    state = box_sim.start(params)
    # The simulation's own forward pass (a reset runs none): one short step holding still.
    ee = state.info["ee_xy_true"]
    state = box_sim.step(state, action_for(ee, ee, a_s_for(10)))
    env, ids = box_sim.env, box_sim.env.ids
    for i, p in enumerate(params):
        m = env.model(jax.tree.map(lambda x: x, p))
        assert float(m.body_mass[ids.object_body]) == pytest.approx(float(p.mass))
        # The joint-space inertia of the object's translation is its mass.
        qm = np.asarray(state.pipeline_state._impl.M[i])
        v = ids.object_qvel
        assert qm[v, v] == pytest.approx(float(p.mass), rel=1e-5)
        # The object-table contacts carry the object's sampled sliding friction (MuJoCo's max rule).
        con = state.pipeline_state._impl.contact
        pair = np.sort(np.asarray(con.geom[i]), axis=-1)
        table = np.all(pair == sorted((ids.object_geom, ids.table_geom)), axis=-1)
        assert table.any()
        np.testing.assert_allclose(np.asarray(con.friction[i])[table, 0], float(p.friction[0]), rtol=1e-6)


def test_the_unrolled_cholesky_solves_damped_gram_systems():
    """controller.spd_solve against a float64 general solve on the controller's kind of system
    (J J^T + lambda^2 I for 4 and 5 rows, near-singular Jacobians included)."""
    rng = np.random.default_rng(0)
    for n in (4, 5):
        for scale in (1.0, 1e-3):  # a well-conditioned Jacobian and one near a singularity
            jac = rng.normal(size=(n, 6)) * np.r_[np.ones(n - 1), scale][:, None]
            a = jac @ jac.T + 0.2**2 * np.eye(n)
            b = rng.normal(size=n)
            want = np.linalg.solve(a, b)
            got = np.asarray(controller.spd_solve(jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)))
            np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


def test_controller_tracks_target_and_keeps_rod_vertical(box_sim):
    # Object far out of the way; four different flange targets.
    params = [make_params("box", start=(-0.1, -0.1, 0.0))] * B
    state = box_sim.start(params)
    home = np.asarray(HOME_XY)
    targets = home + np.array([[0.08, 0.05], [-0.05, 0.1], [0.1, -0.06], [0.0, -0.1]])
    err0 = np.linalg.norm(targets - np.asarray(state.info["ee_xy_true"]), axis=1)
    tilt, herr = 0.0, 0.0
    for _ in range(6):  # 3.6 s, re-commanding the same absolute target
        state = box_sim.step(state, action_for(state.info["ee_xy_true"], targets, 1.0))
        tilt = max(tilt, float(np.max(state.info["max_tilt"])))
        herr = max(herr, float(np.max(state.info["max_height_error"])))
    err = np.linalg.norm(targets - np.asarray(state.info["ee_xy_true"]), axis=1)
    # Unit-gain law: the error decays about as exp(-k t), k a little below 1 (damped pseudo-inverse,
    # servo lag; measured k ~ 0.65): after 3.6 s at most 15 % of it is left.
    assert np.all(err < 0.15 * err0 + 1e-3), (err, err0)
    assert np.degrees(tilt) < 2.0
    assert herr < 0.005


def test_exact_substeps_per_environment(box_sim):
    params = [make_params("box", start=(-0.1, -0.1, 0.0))] * B
    state = box_sim.start(params)
    wanted = np.array([10, 137, 455, 600])
    a_s = jnp.asarray([a_s_for(n) for n in wanted])
    ee = state.info["ee_xy_true"]
    actions = jnp.concatenate([jnp.zeros((B, 2)), a_s[:, None]], axis=1)
    t0 = np.asarray(state.pipeline_state.time)
    state = box_sim.step(state, actions)
    np.testing.assert_array_equal(np.asarray(state.info["substeps"]), wanted)
    # The simulation clock of each environment advanced by exactly its own substeps.
    steps_run = np.round((np.asarray(state.pipeline_state.time) - t0) / 0.001)
    np.testing.assert_array_equal(steps_run, wanted)
    assert ee.shape == (B, 2)


def test_pushing_keeps_physics_valid(box_sim, cyl_sim):
    """Push very light and heavy objects with the rod: they move, stay on the table, the rod stays vertical."""
    for sim in (box_sim, cyl_sim):
        kw = dict(start=(0.07, 0.0, 0.3), friction=0.2)
        if sim.geom_type == "box":
            params = [
                make_params("box", sides=(0.05, 0.05), height=0.046, mass=m, **kw) for m in (0.0005, 0.01, 0.5, 2.5)
            ]
        else:
            params = [
                make_params("cylinder", radius=0.04, height=0.046, mass=m, **kw) for m in (0.0005, 0.01, 0.5, 2.5)
            ]
        state = sim.start(params)
        x0 = np.asarray(state.info["object_xy"])[:, 0]
        rest_z = np.asarray(state.info["object_z"])
        target = np.asarray(HOME_XY) + np.array([0.22, 0.0])
        tilt = herr = 0.0
        for _ in range(8):
            state = sim.step(state, action_for(state.info["ee_xy_true"], np.tile(target, (B, 1)), a_s_for(150)))
            tilt = max(tilt, float(np.max(state.info["max_tilt"])))
            herr = max(herr, float(np.max(state.info["max_height_error"])))
            z = np.asarray(state.info["object_z"])
            assert np.all(np.isfinite(z)) and np.all(np.abs(z - rest_z) < 2e-3), (sim.geom_type, z - rest_z)
        moved = np.asarray(state.info["object_xy"])[:, 0] - x0
        assert np.all(moved > 0.02), (sim.geom_type, moved)
        assert np.all(np.asarray(state.info["invalid_count"]) == 0)
        assert np.degrees(tilt) < 2.0, (sim.geom_type, np.degrees(tilt))
        assert herr < 0.005


def test_invalid_states_are_detected_counted_and_reset(box_sim):
    params = [make_params("box")] * B
    state = box_sim.start(params)
    ps = state.pipeline_state
    a = box_sim.env.ids.object_qpos
    qvel = ps.qvel.at[0, 0].set(jnp.nan)  # env 0: NaN
    qpos = ps.qpos.at[1, a + 2].set(scene.TABLE_TOP - 0.2)  # env 1: object below the table
    qpos = qpos.at[2, a].set(1.5)  # env 2: object off the table
    state = state.replace(pipeline_state=ps.replace(qpos=qpos, qvel=qvel))
    state = box_sim.step(state, jnp.tile(jnp.array([0.0, 0.0, -1.0]), (B, 1)))
    np.testing.assert_array_equal(np.asarray(state.info["invalid_count"]), [1, 1, 1, 0])
    np.testing.assert_array_equal(np.asarray(state.info["episode_invalid"]), [True, True, True, False])
    for leaf in jax.tree.leaves(state.obs) + [state.pipeline_state.qpos, state.pipeline_state.qvel, state.reward]:
        assert np.all(np.isfinite(np.asarray(leaf, np.float32)))
    # The flagged environments restart from their episode's initial state.
    np.testing.assert_allclose(
        np.asarray(state.info["object_xy"])[:3], np.asarray(params[0].start[:2])[None].repeat(3, 0), atol=1e-6
    )
    # The flag is sticky within the episode; the next step of a valid env stays valid.
    state = box_sim.step(state, jnp.tile(jnp.array([0.0, 0.0, -1.0]), (B, 1)))
    np.testing.assert_array_equal(np.asarray(state.info["episode_invalid"]), [True, True, True, False])
    np.testing.assert_array_equal(np.asarray(state.info["invalid_count"]), [1, 1, 1, 0])


def test_non_finite_action_is_zeroed_and_counted(box_sim):
    state = box_sim.start([make_params("box")] * B)
    actions = jnp.array([[jnp.nan, 0.0, 0.0], [0.1, jnp.inf, 0.0], [5.0, -5.0, 9.0], [0.0, 0.0, 0.0]])
    state = box_sim.step(state, actions)
    np.testing.assert_array_equal(np.asarray(state.info["bad_actions"]), [1, 1, 0, 0])
    assert np.all(np.isfinite(np.asarray(state.pipeline_state.qpos)))
    # Out-of-range values are clipped: a_s = 9 runs the maximum of 600 substeps.
    assert int(state.info["substeps"][2]) == 600


def test_wrong_action_shape_raises(box_sim):
    state = box_sim.start([make_params("box")] * B)
    with pytest.raises(ValueError, match=r"action must have shape \(3,\)"):
        jax.vmap(box_sim.env.step)(state, jnp.zeros((B, 2)))


def test_reset_computes_what_the_first_step_reads(box_sim):
    """Reset runs no forward pass (the arm's kinematics at home are computed once on the host): what the
    controller reads before the first step (the flange's pose and Jacobian) matches a full forward
    pass of each episode's own model, and physics stepped from the reset's data matches physics
    stepped from the full pass exactly, contacts included (the rod pushes the objects)."""
    from mujoco import mjx

    params = [
        make_params("box", sides=(0.05, 0.05), height=0.046, mass=m, start=(0.05, 0.0, 0.3))
        for m in (0.01, 0.1, 0.3, 0.5)
    ]
    state = box_sim.start(params)
    env, ids = box_sim.env, box_sim.env.ids
    models = jax.vmap(env.model)(state.info["params"])
    # Placed on one device like the forward pass's output: jit keys its programs on whether arguments
    # are committed to a device, so the reset's own (uncommitted) arrays would compile every program twice.
    kin = jax.device_put(state.pipeline_state, jax.devices()[0])
    full = jax.jit(jax.vmap(mjx.forward))(models, kin)

    def flange(m, d):
        p = d.site_xpos[ids.flange_site]
        return p, d.site_xmat[ids.flange_site], mjx.jac(m, d, p, ids.link7_body)[0]

    # Two compiled programs (reset, forward): equal to rounding.
    read = jax.jit(jax.vmap(flange))
    for x, y in zip(read(models, kin), read(models, full)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), atol=1e-6)
    # Joint velocities that drive the rod into the object: contacts appear in the first substeps.
    ctrl = jnp.tile(jnp.asarray([0.0, 0.6, 0.0, 0.6, 0.0, -0.3, 0.0]), (B, 1))
    step = jax.jit(jax.vmap(lambda m, d: mjx.step(m, d.replace(ctrl=ctrl[0]))))
    a, b = kin, full
    for _ in range(200):
        a, b = step(models, a), step(models, b)
    assert step._cache_size() == 1  # one program steps both, so they must agree exactly
    o = ids.object_qpos
    moved = np.linalg.norm(np.asarray(a.qpos[:, o : o + 2] - kin.qpos[:, o : o + 2]), axis=1)
    assert np.all(moved > 1e-3), moved  # the rod pushed every object
    for name in ("qpos", "qvel", "qacc"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)

"""The scene as built in code (docs/task.md section 1), checked with CPU MuJoCo."""

import mujoco
import numpy as np
import pytest

from mjx_push import scene


@pytest.mark.parametrize("shape", scene.SHAPES)
def test_home_kinematics_match_spec(shape):
    m = scene.build_model(shape)
    d = mujoco.MjData(m)
    d.qpos[:7] = scene.HOME_QPOS
    mujoco.mj_forward(m, d)
    ids = scene.scene_ids(m)
    np.testing.assert_allclose(d.site_xpos[ids.flange_site], [0.4154, 0.0, 0.5905], atol=5e-4)
    tip = d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "rod_tip")]
    assert 0.015 < tip[2] - scene.TABLE_TOP < 0.025  # "about 2 cm above the table top"
    # Flange z axis points down (rod perpendicular to the table) within a degree at home.
    z = d.site_xmat[ids.flange_site].reshape(3, 3)[:, 2]
    assert np.degrees(np.arccos(-z[2])) < 1.0


def test_dynamics_parameters():
    m = scene.build_model("box")
    links = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"link{i}") for i in range(1, 8)]
    assert m.body_mass[links[0]] == pytest.approx(4.970684)
    assert m.body_mass[links[6]] == pytest.approx(0.735522)
    for name in ["link1", "link7", "mount", "rod"]:
        assert m.body_gravcomp[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)] == 1.0
    np.testing.assert_allclose(m.dof_damping[:7], scene.JOINT_DAMPING)
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], scene.KV)
    np.testing.assert_allclose(m.jnt_range[:7], scene.JOINT_RANGE)
    assert m.opt.timestep == 0.001 and m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert np.all(m.geom_condim == 3)


@pytest.mark.parametrize("shape", scene.SHAPES)
def test_only_rod_object_table_collide(shape):
    m = scene.build_model(shape)
    ids = scene.scene_ids(m)
    allowed = {
        frozenset(p)
        for p in [(ids.rod_geom, ids.object_geom), (ids.object_geom, ids.table_geom), (ids.rod_geom, ids.table_geom)]
    }
    found = set()
    for a in range(m.ngeom):
        for b in range(a + 1, m.ngeom):
            if (m.geom_contype[a] & m.geom_conaffinity[b]) or (m.geom_contype[b] & m.geom_conaffinity[a]):
                found.add(frozenset((a, b)))
    assert found == allowed
    assert m.geom_type[ids.rod_geom] == mujoco.mjtGeom.mjGEOM_CAPSULE
    expected = mujoco.mjtGeom.mjGEOM_BOX if shape == "box" else mujoco.mjtGeom.mjGEOM_CYLINDER
    assert m.geom_type[ids.object_geom] == expected


def test_bad_shape_name():
    with pytest.raises(ValueError, match="shape must be one of"):
        scene.build_model("sphere")

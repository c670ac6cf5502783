"""benchmarks.shape_programs: the merged model it times is the scene's box model plus a parked cylinder
that collides like the object (so its cost is that of a batch holding both shapes)."""

import mujoco
import numpy as np
import pytest

from benchmarks import shape_programs
from mjx_push import scene


def test_both_shapes_model_is_the_box_scene_with_a_parked_colliding_cylinder():
    box, both = scene.build_model("box"), shape_programs.model("both")
    assert both.ngeom == box.ngeom + 1
    obj = mujoco.mj_name2id(both, mujoco.mjtObj.mjOBJ_GEOM, "object")
    cyl = mujoco.mj_name2id(both, mujoco.mjtObj.mjOBJ_GEOM, "object_cylinder")
    assert both.geom_type[obj] == mujoco.mjtGeom.mjGEOM_BOX
    assert both.geom_type[cyl] == mujoco.mjtGeom.mjGEOM_CYLINDER
    assert both.geom_bodyid[cyl] == both.geom_bodyid[obj]  # moves with the object
    assert both.geom_contype[cyl] == both.geom_contype[obj]
    assert both.geom_conaffinity[cyl] == both.geom_conaffinity[obj]
    assert both.geom_pos[cyl][2] == pytest.approx(1.0)  # parked far above the table: no contact
    np.testing.assert_allclose(both.body_mass, box.body_mass)  # the parked geom adds no mass
    d = mujoco.MjData(both)
    mujoco.mj_forward(both, d)
    touching = {(d.contact.geom1[i], d.contact.geom2[i]) for i in range(d.ncon)}
    assert not any(cyl in pair for pair in touching)
    assert shape_programs.model("cylinder").ngeom == box.ngeom

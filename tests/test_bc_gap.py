"""benchmarks/bc_gap.py's arithmetic: the yaw-blind expert, the yaw floor and the shape groups, on
hand-built states (no simulation here; the benchmark itself plays the episodes)."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.bc_gap import blind_expert, shape_of, yaw_floor, yaw_shifts
from mjx_push import expert
from mjx_push.train import presets
from mjx_push.train.push_task import PRIV, PRIV_DIM, expert_ground_truth

CFG = presets.make("vpm", "cpu")


def _priv(obj, yaw, ee, size, is_box):
    """One privileged state with the fields the expert reads (the rest zero)."""
    p = np.zeros(PRIV_DIM, np.float32)
    p[PRIV["object_xy"]] = obj
    p[PRIV["object_yaw_cos_sin"]] = [np.cos(yaw), np.sin(yaw)]
    p[PRIV["ee_xy"]] = ee
    p[PRIV["size"]] = size
    p[PRIV["is_box"]] = float(is_box)
    return p


GOAL = np.array([0.6, 0.1], np.float32)
# The rod behind the object but not yet at its push point: the expert repositions, and how far it
# must go depends on the footprint's extent along the push line, so on a cuboid's yaw.
CYL = _priv([0.5, 0.0], 0.3, [0.45, -0.05], [0.03, 0.03, 0.03], False)
SQUARE = _priv([0.5, 0.0], 0.3, [0.45, -0.05], [0.025, 0.025, 0.03], True)
RECT = _priv([0.5, 0.0], 0.3, [0.45, -0.05], [0.04, 0.02, 0.03], True)


def _gt(p):
    return expert_ground_truth(jnp.asarray(p), jnp.asarray(GOAL))


def test_shape_groups_and_symmetry_periods():
    assert shape_of(np.stack([CYL, SQUARE, RECT])).tolist() == [0, 1, 2]
    np.testing.assert_allclose(
        yaw_shifts(jnp.asarray(SQUARE[PRIV["size"]]), 4), [0, np.pi / 8, np.pi / 4, 3 * np.pi / 8]
    )
    np.testing.assert_allclose(yaw_shifts(jnp.asarray(RECT[PRIV["size"]]), 2), [0, np.pi / 2])


def test_the_blind_expert_ignores_the_yaw_and_matches_the_expert_where_yaw_does_not_matter():
    blind = blind_expert(CFG, 8)
    act = lambda p: np.asarray(expert.act(CFG.expert, CFG.env, _gt(p)))  # noqa: E731
    # A cylinder has no orientation: the blind expert is the expert.
    np.testing.assert_allclose(np.asarray(blind(_gt(CYL))), act(CYL), atol=1e-6)
    # A cuboid: the expert's action depends on the yaw, the blind one's does not (over the grid's step).
    turned = _priv([0.5, 0.0], 0.3 + np.pi / 16, [0.45, -0.05], [0.025, 0.025, 0.03], True)
    assert np.abs(act(SQUARE) - act(turned)).max() > 1e-3
    np.testing.assert_allclose(np.asarray(blind(_gt(SQUARE))), np.asarray(blind(_gt(turned))), atol=1e-5)


def test_yaw_floor_is_zero_for_cylinders_and_positive_for_cuboids():
    priv = np.stack([CYL, SQUARE, RECT])
    goal = np.broadcast_to(GOAL, (3, 2))
    floor, first = yaw_floor(CFG, priv, goal, 8)
    # The first yaw is the true one: its action is the expert's label.
    for i, p in enumerate(priv):
        np.testing.assert_allclose(first[i], np.asarray(expert.act(CFG.expert, CFG.env, _gt(p))), atol=1e-6)
    assert floor[0] == pytest.approx(0.0, abs=1e-10)
    assert floor[1] > 0 and floor[2] > floor[1]  # a longer, thinner footprint: more depends on its yaw


def test_expert_modes_name_what_the_expert_does_at_each_state():
    from benchmarks.bc_gap import expert_modes

    states = {
        "hold": _priv([0.599, 0.1], 0.0, [0.55, 0.05], [0.03, 0.03, 0.03], False),  # 1.4 mm from the goal
        "push": _priv([0.5, 0.0], 0.0, [0.5 - 0.05 / np.sqrt(2), -0.05 / np.sqrt(2)], [0.03, 0.03, 0.03], False),
        "approach": CYL,  # on the push line, 7 cm behind the object: straight in to the push point
        "circle": _priv([0.5, 0.0], 0.0, [0.55, 0.05], [0.03, 0.03, 0.03], False),  # between object and goal
    }
    priv = np.stack(list(states.values()))
    modes = expert_modes(CFG, priv, np.broadcast_to(GOAL, (4, 2)))
    assert [expert.MODES[k] for k in modes] == list(states)
    # The action is the one of the displacement that mode plans: none while holding.
    disp, m = expert.plan(CFG.expert, _gt(states["hold"]))
    assert int(m) == 0 and np.allclose(np.asarray(disp), 0.0)


def test_circling_reads_the_rods_angle_off_the_push_line_and_which_way_an_action_turns():
    from benchmarks.bc_gap import circling

    obj = [0.5, 0.0]  # the goal at +x from it: the push line runs along x, behind is -x
    goal = np.broadcast_to(np.array([0.6, 0.0], np.float32), (3, 2))
    priv = np.stack([_priv(obj, 0.0, ee, [0.03, 0.03, 0.03], False) for ee in ([0.4, 0.0], [0.5, 0.1], [0.58, 0.0])])
    off, _, label_turn = circling(priv, goal, np.zeros((3, 3)), np.zeros((3, 3)))
    np.testing.assert_allclose(off, [0.0, 90.0, 180.0], atol=1e-4)  # behind, beside, right in front
    # The expert's own way round from in front (its circling step), against an actor that goes the
    # other way: opposite signs across the object->rod direction.
    front = priv[2]
    label = np.asarray(expert.act(CFG.expert, CFG.env, expert_ground_truth(jnp.asarray(front), jnp.asarray(goal[0]))))
    mirrored = label * np.array([1.0, -1.0, 1.0])  # the same step mirrored across the push line
    _, actor_turn, label_turn = circling(front[None], goal[:1], mirrored[None], label[None])
    assert abs(label_turn[0]) > 0.1 and np.sign(actor_turn[0]) == -np.sign(label_turn[0])

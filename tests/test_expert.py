"""The scripted expert (mjx_push/expert.py): its geometry and action inversion on known values and its
baseline row in `mjx-push reproduce` (that it pushes every standard episode to within 1 cm:
benchmarks/learning_checks.py, expert-1cm)."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import math

import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import expert
from mjx_push.env import EnvConfig, decode_substeps
from mjx_push.train import presets


def test_support_and_bounding_radius():
    size = jnp.array([0.04, 0.02, 0.03])  # box half extents
    assert float(expert.support(size, True, 0.0, jnp.array([1.0, 0.0]))) == pytest.approx(0.04)
    assert float(expert.support(size, True, math.pi / 2, jnp.array([1.0, 0.0]))) == pytest.approx(0.02, abs=1e-6)
    diag = jnp.array([1.0, 1.0]) / math.sqrt(2)
    assert float(expert.support(size, True, 0.0, diag)) == pytest.approx(0.06 / math.sqrt(2))
    assert float(expert.support(jnp.array([0.05, 0.02, 0.0]), False, 1.0, diag)) == pytest.approx(0.05)
    assert float(expert.bounding_radius(size, True)) == pytest.approx(math.hypot(0.04, 0.02))


def test_displacement_action_inverts_the_step_response():
    cfg, env = expert.ExpertConfig(), presets.ACTION_BOX
    env = EnvConfig(**env)
    a = expert.displacement_action(cfg, env, jnp.array([0.01, -0.02]), short=jnp.asarray(False))
    n = int(decode_substeps(a[2], env.substeps))
    k = cfg.response_rate * env.controller.gain
    frac = 1 - math.exp(-k * (n - cfg.dead_substeps))
    # The step settles to `settle` of its offset (rounded up to whole substeps) and covers the displacement.
    assert frac >= cfg.settle - 1e-3 and frac < cfg.settle + 0.02
    np.testing.assert_allclose(np.asarray(a[:2]) * env.action_scale * frac, [0.01, -0.02], rtol=1e-3)
    hold = expert.displacement_action(cfg, env, jnp.zeros(2), short=jnp.asarray(True))
    assert int(decode_substeps(hold[2], env.substeps)) == env.substeps[0] and np.all(hold[:2] == 0)
    big = expert.displacement_action(cfg, env, jnp.array([1.0, 0.0]), short=jnp.asarray(False))
    assert float(big[0]) == 1.0  # clipped to the action box
    with pytest.raises(ValueError, match="expert.settle"):
        expert.ExpertConfig(settle=1.0)


def test_hold_stands_still_with_short_steps_or_with_the_usual_length():
    env = EnvConfig(**presets.ACTION_BOX)
    gt = {
        "ee_xy": jnp.array([0.45, -0.05]),
        "object_xy": jnp.array([0.5, 0.0]),
        "object_yaw": jnp.asarray(0.3),
        "goal_xy": jnp.array([0.501, 0.001]),  # 1.4 mm from the object: inside the hold radius
        "size": jnp.array([0.03, 0.03, 0.03]),
        "is_box": jnp.asarray(False),
    }
    away = {**gt, "goal_xy": jnp.array([0.6, 0.1])}
    short = np.asarray(expert.act(expert.ExpertConfig(), env, gt))
    usual = np.asarray(expert.act(expert.ExpertConfig(hold_short=False), env, gt))
    moving = np.asarray(expert.act(expert.ExpertConfig(hold_short=False), env, away))
    assert np.all(short[:2] == 0) and np.all(usual[:2] == 0)  # both stand still
    assert int(decode_substeps(short[2], env.substeps)) == env.substeps[0]
    assert usual[2] == pytest.approx(moving[2]) and usual[2] > 0.5  # no jump in a_s at the hold radius
    with pytest.raises(ValueError, match="expert.hold_short"):
        expert.ExpertConfig(hold_short=1)


def test_push_fraction_pushes_a_share_of_the_remaining_distance():
    r = 0.005 / math.sqrt(2)  # the goal 5 mm ahead along (1, 1); the rod touching the object from behind
    back = (0.03 + 0.0075) / math.sqrt(2)  # rod centre: object radius + rod radius (scene.ROD_RADIUS)
    gt = {
        "ee_xy": jnp.array([0.5 - back, -back]),
        "object_xy": jnp.array([0.5, 0.0]),
        "object_yaw": jnp.asarray(0.0),
        "goal_xy": jnp.array([0.5 + r, r]),
        "size": jnp.array([0.03, 0.03, 0.03]),
        "is_box": jnp.asarray(False),
    }
    for f in (1.0, 0.6):
        disp, m = expert.plan(expert.ExpertConfig(push_fraction=f), gt)
        assert expert.MODES[int(m)] == "push"
        np.testing.assert_allclose(np.asarray(disp), [f * r, f * r], atol=1e-6)
    far = {**gt, "goal_xy": jnp.array([0.6, 0.1])}  # 14 cm: the step cap, whatever the fraction
    disp, _ = expert.plan(expert.ExpertConfig(push_fraction=0.6), far)
    assert float(jnp.linalg.norm(disp)) == pytest.approx(expert.ExpertConfig().max_push, rel=1e-5)
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match="expert.push_fraction"):
            expert.ExpertConfig(push_fraction=bad)


def test_circle_cut_sends_the_rod_round_one_side_from_in_front_of_the_object():
    """The rod between the object and its goal (after an overshoot): the short way round flips side on
    a millimetre, a cut below pi does not; either way the rod goes round, never through the object."""
    gt = {
        "object_xy": jnp.array([0.5, 0.0]),
        "object_yaw": jnp.asarray(0.0),
        "goal_xy": jnp.array([0.6, 0.0]),
        "size": jnp.array([0.03, 0.03, 0.03]),
        "is_box": jnp.asarray(False),
    }

    def move(cfg, x, y):
        disp, m = expert.plan(cfg, {**gt, "ee_xy": jnp.array([x, y])})
        assert expert.MODES[int(m)] == "circle"
        return np.asarray(disp)

    def sideways(cfg, y):  # the y of the rod's move from (0.55, y): which side it goes round
        return float(move(cfg, 0.55, y)[1])

    short, cut = expert.ExpertConfig(), expert.ExpertConfig(circle_cut=2.2)
    assert sideways(short, 0.002) > 0 > sideways(short, -0.002)  # the short way: either side
    assert sideways(cut, 0.002) < 0 and sideways(cut, -0.002) < 0  # one side
    assert sideways(cut, 0.01) < 0 and sideways(cut, -0.01) < 0
    # Beside the object (90 degrees off the line, short of the cut): the short way, back behind it.
    np.testing.assert_allclose(move(cut, 0.5, 0.05), move(short, 0.5, 0.05))
    assert move(cut, 0.5, 0.05)[0] < 0
    for bad in (0.0, 4.0):
        with pytest.raises(ValueError, match="expert.circle_cut"):
            expert.ExpertConfig(circle_cut=bad)


def test_reproduce_has_an_expert_baseline_row(tmp_path):
    from mjx_push.train.comparison.reproduce import expert_job
    from mjx_push.train.comparison.study import Study

    lines = []
    study = Study("cpu", tmp_path, episodes=4, shapes=("cylinder",), setting="standard")
    first = expert_job(study, log=lines.append)
    again = expert_job(study, log=lines.append)
    assert first["cylinder"]["success"]["mean"] >= 0.75
    assert any("reusing evaluation" in line for line in lines)
    for metric, v in first["cylinder"].items():
        assert again["cylinder"][metric]["mean"] == pytest.approx(v["mean"], rel=1e-6), metric
    assert (tmp_path / "expert" / "eval-standard-cylinder-4.json").is_file()

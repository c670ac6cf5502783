"""The perturbations of a real cell (mjx_push.perturb) on hand-built inputs, and in CPU MuJoCo: NumPy
only, nothing compiled. The MJX environment's use of them is tested in tests/test_stress.py."""

import mjx_push  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from mjx_push import mask_geometry, perturb, scene
from mjx_push.config import EnvConfig
from mjx_push.errors import ConfigError
from mjx_push.export import camera
from mjx_push.perturb import PerturbConfig

DEPTH = scene.TABLE_TOP - scene.CAMERA_POS[2]  # camera to table plane (m)
PX = DEPTH / mask_geometry.FOCAL  # metres per pixel at the table plane


def record(**values) -> dict:
    """The neutral record with some values changed."""
    r = perturb.neutral_episode()
    for k, v in values.items():
        r[k] = np.asarray(v, np.float64)
    return r


def flat_box(xy, yaw=0.0, sides=(0.063, 0.041)):
    """A box 0.1 mm high: its silhouette is its bottom face, which a camera offset moves rigidly."""
    h = 1e-4
    return mask_geometry.box_mask(np.asarray(xy), yaw, np.asarray(sides) / 2, scene.TABLE_TOP, h)


# --- configuration ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "fields, named",
    [
        (dict(mask_flip=-0.01), "env.perturb.mask_flip"),
        (dict(mask_edge=3.5), "env.perturb.mask_edge"),
        (dict(mask_open_close=1.5), "env.perturb.mask_open_close"),
        (dict(latency=-1), "env.perturb.latency"),
        (dict(latency=2.5), "env.perturb.latency"),
        (dict(camera_shift=float("nan")), "env.perturb.camera_shift"),
        (dict(velocity_gain=True), "env.perturb.velocity_gain"),
        (dict(mass_factor=0.5), "env.perturb.mass_factor"),
        (dict(rod_radius=0.01), "env.perturb.rod_radius"),
        (dict(frame_repeat=0.6, frame_empty=0.6), "env.perturb.frame_repeat + env.perturb.frame_empty"),
        (dict(sample="gaussian"), "env.perturb.sample"),
    ],
)
def test_bad_levels_are_refused_naming_the_field(fields, named):
    with pytest.raises(ConfigError, match=named.replace("+", r"\+")):
        PerturbConfig(**fields)


def test_set_lines_reach_the_environment_and_bad_ones_name_the_field():
    from mjx_push.train import presets

    cfg = presets.make("egru", "cpu")
    line = perturb.set_line(perturb.training_config())
    items = presets.parse_overrides(line.removeprefix("--set ").split())
    assert presets.with_overrides(cfg, items).env.perturb == perturb.training_config()
    with pytest.raises(ConfigError, match="env.perturb.latency must be in"):
        presets.with_overrides(cfg, {"env.perturb.latency": 5000})
    with pytest.raises(ConfigError, match="env.perturb.latency must be an integer"):
        presets.with_overrides(cfg, {"env.perturb.latency": 2.5})
    with pytest.raises(ConfigError, match="no field 'blur'"):
        presets.with_overrides(cfg, {"env.perturb.blur": 1})
    # A record written before perturbations existed reads back clean.
    old = presets.config_dict(cfg)
    del old["env"]["perturb"]
    assert presets.config_from_dict(old).env.perturb == PerturbConfig()


def test_the_documented_training_line_and_the_studys_randomised_arm_are_the_realistic_randomisation():
    import json

    repo = Path(__file__).resolve().parents[1]
    line = perturb.set_line(perturb.training_config("realistic"))
    assert line in (repo / "docs" / "robust-training.md").read_text()
    # robust-v1: the randomised arm trains with exactly that line, the plain arm with none, and
    # nothing else differs between the two protocols but their names.
    arms = {
        a: json.loads((repo / "docs/data/robust-v1" / a / "protocol.json").read_text()) for a in ("plain", "randomised")
    }
    assert arms["randomised"].pop("set") == line.removeprefix("--set ").split() and "set" not in arms["plain"]
    assert {k: v for k, v in arms["plain"].items() if k != "version"} == {
        k: v for k, v in arms["randomised"].items() if k != "version"
    }


def test_suite_levels_grow_and_every_row_is_a_valid_config():
    for name, fields in perturb.SUITE.items():
        for f, values in fields.items():
            assert len(values) == 3 and all(abs(a) <= abs(b) for a, b in zip(values, values[1:])), name
        for level in perturb.LEVELS:
            assert perturb.suite_config([name], level).active() == set(fields)
    with pytest.raises(ConfigError, match="level must be one of"):
        perturb.suite_config(["camera"], "extreme")


# --- one episode's record -------------------------------------------------------------------------------
def test_fixed_records_apply_each_magnitude_exactly_in_a_drawn_direction():
    cfg = perturb.suite_config(list(perturb.SUITE), "severe")
    u = np.random.default_rng(0).random((200, perturb.N_UNIFORMS))
    r = perturb.draw_episode(cfg, u)
    np.testing.assert_allclose(np.hypot(r["camera"][:, 0], r["camera"][:, 1]), cfg.camera_shift)
    assert set(np.round(r["camera"][:, 2], 12)) == {round(-cfg.camera_yaw, 12), round(cfg.camera_yaw, 12)}
    assert np.all(r["latency"] == cfg.latency)
    assert set(np.round(r["mass"], 12)) == {round(1 / cfg.mass_factor, 12), cfg.mass_factor}
    assert set(np.round(r["gain"], 12)) == {1 - cfg.velocity_gain, 1 + cfg.velocity_gain}
    np.testing.assert_allclose(r["lag"], cfg.velocity_lag / (cfg.velocity_lag + 1))
    np.testing.assert_allclose(np.abs(r["rod"]), [[cfg.rod_radius, cfg.rod_length]] * 200)
    assert np.all(r["edge"] == cfg.mask_edge) and np.all(r["flip"] == cfg.mask_flip)


def test_uniform_records_stay_within_each_magnitude_and_cover_both_directions():
    cfg = perturb.training_config("severe")
    u = np.random.default_rng(1).random((2000, perturb.N_UNIFORMS))
    r = perturb.draw_episode(cfg, u)
    assert np.all(np.hypot(r["camera"][:, 0], r["camera"][:, 1]) <= cfg.camera_shift)
    assert r["edge"].min() < -1.5 and r["edge"].max() > 1.5 and np.all(np.abs(r["edge"]) <= 2)
    assert set(np.unique(r["latency"])) == set(range(cfg.latency + 1))
    assert r["mass"].min() < 1 / 3.5 and r["mass"].max() > 3.5 and np.all(r["mass"] <= 4 + 1e-12)
    assert np.all((r["flip"] >= 0) & (r["flip"] <= cfg.mask_flip))


def test_the_neutral_record_is_what_a_neutral_config_draws():
    u = np.random.default_rng(2).random(perturb.N_UNIFORMS)
    drawn = perturb.draw_episode(PerturbConfig(sample="uniform"), u)
    for k, v in perturb.neutral_episode().items():
        np.testing.assert_array_equal(np.abs(drawn[k]), np.abs(v))
    assert set(perturb.neutral_episode()) == set(perturb.EPISODE_KEYS)


# --- masks and the camera -------------------------------------------------------------------------------
def test_a_camera_offset_shifts_the_mask_by_the_right_pixels():
    xy = np.array([0.4537, 0.0213])
    m0 = flat_box(xy, 0.0)
    assert 20 < m0.sum() and not (m0[0].any() or m0[-1].any() or m0[:, 0].any() or m0[:, -1].any())
    # The camera 3 pixels further along +x and 2 along +y: the object shows 3 columns and 2 rows lower.
    xy1, yaw1 = perturb.camera_view(xy, 0.0, np.array([3 * PX, 2 * PX, 0.0]))
    np.testing.assert_array_equal(flat_box(xy1, yaw1), np.roll(m0, (-2, -3), axis=(0, 1)))
    # A real object (its top face nearer the camera) moves by the same pixels at its centroid.
    size = np.array([0.03, 0.02, 0.025])
    z = scene.TABLE_TOP + size[2]
    a = mask_geometry.object_mask("box", size, xy, 0.3, z)
    b = mask_geometry.object_mask("box", size, *perturb.camera_view(xy, 0.3, np.array([3 * PX, 0.0, 0.0])), z)
    cols = np.arange(64)
    shift = (a.sum(0) @ cols) / a.sum() - (b.sum(0) @ cols) / b.sum()
    assert shift == pytest.approx(3.0, abs=0.35)


def test_a_camera_turned_about_its_axis_turns_the_mask():
    c = scene.CAMERA_POS[:2]
    m0 = mask_geometry.box_mask(c, 0.3, np.array([0.04, 0.015]), scene.TABLE_TOP, 0.03)
    xy1, yaw1 = perturb.camera_view(c, 0.3, np.array([0.0, 0.0, math.pi / 2]))
    np.testing.assert_array_equal(
        mask_geometry.box_mask(xy1, yaw1, np.array([0.04, 0.015]), scene.TABLE_TOP, 0.03), np.rot90(m0)
    )


def test_edge_and_open_close_are_the_camera_pipelines_morphology():
    m = mask_geometry.object_mask("box", np.array([0.03, 0.02, 0.025]), np.array([0.45, 0.02]), 0.4, 0.425)
    m[5, 5] = True  # a speck the opening removes
    np.testing.assert_array_equal(perturb.edge(m, -1, 2), camera.erode(m, 3))
    np.testing.assert_array_equal(perturb.edge(m, 2, 2), camera.dilate(m, 5))
    np.testing.assert_array_equal(perturb.edge(m, 0, 2), m)
    opened = camera.dilate(camera.erode(m, 3), 3)
    np.testing.assert_array_equal(perturb.open_close(m, 1, 2), camera.erode(camera.dilate(opened, 3), 3))
    assert not perturb.open_close(m, 1, 2)[5, 5]
    # A fractional level: one pixel more on that fraction of frames.
    assert perturb.frame_edge(-0.5, 0.2) == -1 and perturb.frame_edge(-0.5, 0.7) == 0
    assert perturb.frame_edge(1.5, 0.4) == 2 and perturb.frame_edge(1.5, 0.6) == 1


def test_flips_and_missed_frames_change_what_they_say():
    m = flat_box([0.45, 0.0])
    u = np.random.default_rng(3).random(m.shape)
    got = perturb.camera_mask(m, record(flip=0.01), 0.5, u, 0, 0)
    np.testing.assert_array_equal(got ^ m, u < 0.01)
    shown = np.roll(m, 5, axis=1)
    r = record(empty=0.1, repeat=0.2)
    assert not perturb.missed_frame(m, shown, r, 0.05).any()
    np.testing.assert_array_equal(perturb.missed_frame(m, shown, r, 0.15), shown)
    np.testing.assert_array_equal(perturb.missed_frame(m, shown, r, 0.35), m)


def test_the_servo_runs_the_gain_and_a_first_order_lag():
    dq = np.array([0.2, -0.1, 0.3, 0.0, 0.05, -0.4, 0.0])
    np.testing.assert_allclose(perturb.actuate(dq, np.zeros(7), record(gain=0.8)), 0.8 * dq)
    r, applied = record(lag=0.9), np.zeros(7)
    for _ in range(10):
        applied = perturb.actuate(dq, applied, r)
    np.testing.assert_allclose(applied, dq * (1 - 0.9**10))


def test_object_and_rod_factors():
    from mjx_push.config import ObjectParams

    p = ObjectParams(
        size=np.array([0.03, 0.02, 0.025]),
        mass=np.array(0.5),
        inertia=np.array([1e-4, 2e-4, 3e-4]),
        friction=np.array([0.2, 0.005, 0.0001]),
        start=np.zeros(3),
        goal=np.zeros(3),
    )
    q = perturb.scale_object(p, record(mass=4.0, friction=0.5))
    assert q.mass == 2.0 and q.friction[0] == 0.1 and q.friction[1] == 0.005
    np.testing.assert_allclose(q.inertia, 4 * p.inertia)
    size, pos, rbound, aabb = perturb.rod_geometry(
        np.array([0.0075, 0.07, 0.0]), np.zeros(3), 0.0775, np.array([0, 0, 0, 0.0075, 0.0075, 0.0775]), [0.001, -0.002]
    )
    np.testing.assert_allclose(size, [0.0085, 0.069, 0.0])
    np.testing.assert_allclose(pos, [0, 0, -0.001])  # the end at the flange stays put
    assert rbound == pytest.approx(0.0775)
    np.testing.assert_allclose(aabb[3:], [0.0085, 0.0085, 0.0775])


# --- CPU MuJoCo ---------------------------------------------------------------------------------------
ALL_ON = perturb.suite_config(list(perturb.SUITE), "severe")


def cpu_env(perturbations=PerturbConfig(), **fields):
    from mjx_push.export.cpu_env import CpuPushEnv

    cfg = dataclasses.replace(EnvConfig(substeps=(10, 60), perturb=perturbations), **fields)
    return CpuPushEnv(cfg, "box", mask_source="analytic")


def params():
    from tests.helpers import make_params

    p = make_params("box", mass=0.5)
    return type(p)(**{k: np.asarray(getattr(p, k)) for k in p.__dataclass_fields__})


def run(env, perturbation=None, steps=3):
    kw = {} if perturbation is None else {"perturbation": perturbation}
    out = [env.reset(seed=4, params=params(), **kw)]
    for a in ([0.02, -0.01, 0.5], [-0.01, 0.0, -0.2], [0.0, 0.03, 0.9])[:steps]:
        out.append(env.step(np.array(a))[0])
    return out, env._s.data.qpos.copy()


def test_cpu_neutral_records_leave_episodes_bitwise_unchanged():
    clean, q_clean = run(cpu_env())
    neutral, q_neutral = run(cpu_env(ALL_ON), perturb.neutral_episode())
    np.testing.assert_array_equal(q_neutral, q_clean)
    for a, b in zip(clean, neutral):
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])
    # ... and a drawn record does change them.
    _, q_drawn = run(cpu_env(ALL_ON))
    assert not np.array_equal(q_drawn, q_clean)


def test_cpu_latency_runs_the_previous_target_for_the_first_substeps(monkeypatch):
    from mjx_push.export import cpu_env as cpu_mod

    env = cpu_env(PerturbConfig(latency=30))
    env.reset(seed=0, params=params(), perturbation=record(latency=7))
    seen = []
    law = cpu_mod.ctl.joint_velocity
    monkeypatch.setattr(
        cpu_mod.ctl, "joint_velocity", lambda m, d, t, i, c: seen.append(t.copy()) or law(m, d, t, i, c)
    )
    home = env.home_flange.copy()
    env.step(np.array([0.02, 0.01, 1.0]))  # 60 substeps
    new = env.target.copy()
    assert len(seen) == 60 and not np.allclose(new, home)
    np.testing.assert_array_equal(seen[:7], [home] * 7)
    np.testing.assert_array_equal(seen[7:], [new] * 53)
    seen.clear()
    env.step(np.array([0.0, -0.02, -1.0]))  # 10 substeps: the last step's target runs for the first 7
    np.testing.assert_array_equal(seen[:7], [new] * 7)
    assert not np.allclose(seen[7], new)


def test_cpu_mass_outside_the_range_and_the_rod_reach_the_model():
    env = cpu_env(ALL_ON)
    env.reset(seed=0, params=params(), perturbation=record(mass=4.0, rod=[0.002, -0.002]))
    m, ids = env._s.model, env._s.ids
    assert env.config.objects.mass[1] == 1.0 and m.body_mass[ids.object_body] == pytest.approx(2.0)
    assert m.body_invweight0[ids.object_body, 0] < 1 / 1.5  # mj_setConst derived it from the new mass
    assert m.geom_size[ids.rod_geom, 0] == pytest.approx(scene.ROD_RADIUS + 0.002)
    env.reset(seed=0, params=params(), perturbation=perturb.neutral_episode())  # the next episode: nominal again
    assert m.geom_size[ids.rod_geom, 0] == pytest.approx(scene.ROD_RADIUS)
    assert m.body_mass[ids.object_body] == pytest.approx(0.5)


def test_cpu_rendered_masks_see_the_camera_offset_as_the_analytic_ones():
    from mjx_push.export.cpu_env import CpuPushEnv
    from tests.helpers import renderer_or_skip

    renderer_or_skip()
    r = record(camera=[4 * PX, -3 * PX, math.radians(10)])
    masks = {}
    for source in ("render", "analytic"):
        env = CpuPushEnv(EnvConfig(perturb=PerturbConfig(camera_shift=0.01, camera_yaw=0.2)), "box", source)
        masks[source] = env.reset(seed=0, params=params(), perturbation=r)["object_mask"]
        env.close()
    a, b = masks["render"], masks["analytic"]
    assert (a & b).sum() / (a | b).sum() >= 0.9
    clean = mask_geometry.object_mask(
        "box", params().size, params().start[:2], params().start[2], scene.TABLE_TOP + 0.025
    )
    assert (a & clean).sum() / (a | clean).sum() < 0.8  # the offset did move the rendered mask

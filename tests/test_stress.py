"""The perturbations in the MJX environment and the stress suite (train/stress.py). Every test shares two
compiled batches of 3 environments, clean and with every perturbation's code (`stress.runner`), on a
task of 3-step episodes of 10-30 substeps: compilation, not simulation, costs."""

import mjx_push  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco import mjx

from mjx_push import mask_geometry, perturb, scene
from mjx_push.env import EnvConfig
from mjx_push.errors import ConfigError
from mjx_push.perturb import PerturbConfig
from mjx_push.train import stress
from mjx_push.train.stress import StressConfig
from tests.helpers import a_s_for, make_params, stack

TASK = EnvConfig(episode_length=3, substeps=(10, 30))
B = 3  # one device: an odd batch is not split over the host devices, and compiles in two thirds the time
LEVELS = ("realistic",)


def run_config(encoder_file):
    from mjx_push.train import presets

    cfg = presets.make("vpm", "smoke")
    return dataclasses.replace(cfg, env=TASK, encoder=encoder_file)


def first(state):
    """Environment 0 of a batched state, as NumPy (slicing every leaf of MJX data eagerly costs seconds)."""
    return jax.tree.map(lambda x: x[0], jax.device_get(state))


@pytest.fixture(scope="module")
def envs():
    """(clean, perturbed) (env, reset, step) of the stress suite's box environment at realistic levels."""
    perturbed = stress.env_config(TASK, StressConfig(levels=LEVELS), "box")
    assert perturbed.perturb.active() == set(perturb.FIELDS)  # every perturbation's code is compiled in
    clean = dataclasses.replace(perturbed, perturb=PerturbConfig())
    return stress.runner(clean, "box", B), stress.runner(perturbed, "box", B)


def episodes():
    p = stack(
        [make_params("box", mass=0.5, start=(0.03 * i, 0.08, 0.1 * i), goal=(0.05, -0.05, 0.2)) for i in range(B)]
    )
    return p, jax.random.split(jax.random.PRNGKey(3), B)


def records(**values):
    r = perturb.neutral_episode()
    r.update({k: np.asarray(v, np.float64) for k, v in values.items()})
    return jax.tree.map(lambda x: np.broadcast_to(x, (B, *np.shape(x))).copy(), r)


def action(ee_xy, target_xy, n):
    a = np.concatenate([np.asarray(target_xy) - np.asarray(ee_xy), np.full((B, 1), a_s_for(n, *TASK.substeps))], 1)
    return jnp.asarray(a, jnp.float32)


def test_neutral_records_leave_mjx_episodes_bitwise_unchanged(envs):
    (_, reset0, step0), (_, reset1, step1) = envs
    p, keys = episodes()
    a, b = reset0(keys, p, records()), reset1(keys, p, records())
    for t in range(3):
        for x, y in ((a.obs, b.obs), (a.pipeline_state.qpos, b.pipeline_state.qpos), (a.reward, b.reward)):
            jax.tree.map(lambda u, v: np.testing.assert_array_equal(np.asarray(u), np.asarray(v)), x, y)
        for k in a.info:
            jax.tree.map(lambda u, v: np.testing.assert_array_equal(np.asarray(u), np.asarray(v)), a.info[k], b.info[k])
        act = action(a.obs["ee_xy"], np.asarray(a.info["object_xy"]) - [0.05, 0.0], 12 + 6 * t)
        a, b = step0(a, act), step1(b, act)
    # A drawn record of the same environment does change the episode.
    drawn = jax.device_get(jax.jit(jax.vmap(envs[1][0].draw_perturbation))(keys))
    c = reset1(keys, p, jax.tree.map(lambda x: np.asarray(x, np.float64), drawn))
    assert not np.array_equal(
        np.asarray(c.obs["object_mask"]), np.asarray(reset0(keys, p, records()).obs["object_mask"])
    )


def test_latency_runs_the_previous_command_for_its_substeps(envs):
    """From rest at home, a step of 20 substeps whose first 10 are late ends where a 10-substep step that
    holds home followed by a 10-substep step to the same target ends."""
    _, reset, step = envs[1]
    p, keys = episodes()
    home = np.tile(np.asarray(scene.home_flange_pos()[:2]), (B, 1))
    target = home + [[0.02, -0.015]] * B
    late = step(reset(keys, p, records(latency=10)), action(home, target, 20))
    s = reset(keys, p, records())
    s = step(s, action(home, home, 10))
    s = step(s, action(np.asarray(s.pipeline_state.site_xpos[:, envs[1][0].ids.flange_site, :2]), target, 10))
    prompt = step(reset(keys, p, records()), action(home, target, 20))
    q_late, q_split, q_prompt = (np.asarray(x.pipeline_state.qpos[:, :7]) for x in (late, s, prompt))
    np.testing.assert_allclose(q_late, q_split, atol=2e-5)
    assert np.abs(q_late - q_prompt).max() > 50 * np.abs(q_late - q_split).max()
    np.testing.assert_array_equal(np.asarray(late.info["target"]), np.asarray(prompt.info["target"]))
    np.testing.assert_allclose(np.asarray(late.info["prev_target"])[:, :2], home, atol=1e-7)  # the next step's late one


def test_a_mass_outside_the_range_reaches_the_physics(envs):
    env, reset, _ = envs[1]
    p, keys = episodes()
    s = reset(keys, p, records(mass=4.0, friction=0.5))
    assert TASK.objects.mass[1] == 1.0
    np.testing.assert_allclose(np.asarray(s.info["params"].mass), 2.0)
    np.testing.assert_allclose(np.asarray(s.info["params"].friction[:, 0]), 0.25)
    one = first(s)
    m = jax.jit(env._model)(one.info["params"], one.info["perturbation"])
    v = env.ids.object_qvel
    d = jax.jit(mjx.forward)(m, one.pipeline_state)  # the episode's model, as its substeps use it (a reset runs none)
    qm = mjx.full_m(m, d)
    np.testing.assert_allclose(np.diag(qm)[v : v + 3], 2.0, rtol=1e-6)
    assert float(m.body_invweight0[env.ids.object_body, 0]) == pytest.approx(0.5, rel=1e-6)
    assert float(m.geom_friction[env.ids.object_geom, 0]) == pytest.approx(0.25)


def test_rod_and_camera_records_reach_the_model_and_the_masks(envs):
    env, reset, _ = envs[1]
    p, keys = episodes()
    px = (scene.TABLE_TOP - scene.CAMERA_POS[2]) / mask_geometry.FOCAL
    cam = np.array([3 * px, -2 * px, 0.02])
    s = reset(keys, p, records(rod=[0.001, -0.001], camera=cam))
    one = first(s)
    m = jax.jit(env._model)(one.info["params"], one.info["perturbation"])
    np.testing.assert_allclose(
        np.asarray(m.geom_size[env.ids.rod_geom, :2]),
        [0.0085, env.mj_model.geom_size[env.ids.rod_geom, 1] - 0.0005],
        rtol=1e-6,
    )
    # The goal mask is the analytic one at the pose the displaced camera shows (float32 vs float64 edges).
    g = np.asarray(one.info["params"].goal, np.float64)
    size = np.asarray(one.info["params"].size, np.float64)
    want = mask_geometry.object_mask("box", size, *perturb.camera_view(g[:2], g[2], cam), scene.TABLE_TOP + size[2])
    assert np.sum(np.asarray(one.info["goal_mask"]) != want) <= 2
    clean = mask_geometry.object_mask("box", size, g[:2], g[2], scene.TABLE_TOP + size[2])
    assert np.sum(clean != want) > 10


def test_bad_stress_settings_are_named():
    for kwargs, message in [
        (dict(perturbations=("blur",)), "perturbations must be among"),
        (dict(levels=("extreme",)), "levels must be among"),
        (dict(shapes=("sphere",)), "shapes must be among"),
        (dict(episodes=0), "episodes must be a positive integer"),
        (dict(levels=()), "levels must list distinct values"),
        (dict(setting="hard"), "setting must be one of"),
    ]:
        with pytest.raises(ConfigError, match=message):
            StressConfig(**kwargs)


def test_stress_suite_end_to_end_for_a_policy_and_the_expert(envs, encoder_file, monkeypatch):
    from mjx_push import encoder as enc
    from mjx_push.train.evaluate import ExpertPolicy
    from mjx_push.train.networks import make_networks
    from mjx_push.train.runs.policies import Policy

    cfg = run_config(encoder_file)
    actor = make_networks(cfg.train.agent).init_actor(jax.random.PRNGKey(0), 3)
    policy = Policy(cfg, actor, enc.init_vae(jax.random.PRNGKey(1))["encoder"], {})
    sc = StressConfig(
        perturbations=("latency", "mask_flip", "all"), levels=LEVELS, shapes=("square",), episodes=3, batch=B
    )
    calls = []  # (object params, environment keys, records) of every batch: one cell each here
    run = stress.run_episodes
    monkeypatch.setattr(stress, "run_episodes", lambda *a: calls.append(a[4:]) or run(*a))
    res = stress.stress(policy, sc)
    monkeypatch.undo()
    (p0, k0, r0), (p1, k1, r1), (p2, k2, r2) = calls[:3]  # clean, noise floor, latency
    np.testing.assert_array_equal(p0.goal, p1.goal)
    assert not np.array_equal(k0, k1) and np.array_equal(k0, k2)  # the floor redraws the noise alone
    assert np.all(r0["latency"] == 0) and np.all(r1["latency"] == 0) and np.all(r2["latency"] == 30)
    rows = {(r["perturbation"], r["level"]): r for r in res["rows"]}
    assert list(rows) == [
        ("clean", None),
        ("noise_floor", None),
        ("latency", "realistic"),
        ("mask_flip", "realistic"),
        ("all", "realistic"),
    ]
    assert rows[("latency", "realistic")]["fields"] == {"latency": 30}
    clean = rows[("clean", None)]["shapes"]["square"]
    assert clean["n"] == 3 and clean["drop"]["mean"] == 0.0
    # The clean row is the clean environment's episodes: run them there directly.
    spec_params, keys = stress.shape_episodes(sc, TASK, "square")
    direct = stress.run_episodes(policy, envs[0][0].config, "box", B, *stress.pad(spec_params, keys, records(), B))
    assert clean["per_episode"]["final_distance"] == [round(float(x), 6) for x in direct["final_distance"][:3]]
    assert clean["per_episode"]["success"] == [int(x) for x in direct["success"][:3]]
    score = np.mean([rows[(n, "realistic")]["mean"]["success"] for n in ("latency", "mask_flip")])
    assert res["score"]["realistic"] == pytest.approx(score) and res["score"]["rows"] == 2
    json.dumps(res)
    table = stress.format_table(res)
    assert "| latency | realistic | latency 30 ms |" in table and "robustness score" in table
    # The expert feels only the physical rows; the others are its clean row.
    ex = stress.stress(ExpertPolicy(cfg), sc)
    flip = next(r for r in ex["rows"] if r["perturbation"] == "mask_flip")
    assert flip["skipped"] and flip["shapes"] == ex["rows"][0]["shapes"]
    assert next(r for r in ex["rows"] if r["perturbation"] == "noise_floor")["skipped"]
    assert not next(r for r in ex["rows"] if r["perturbation"] == "latency")["skipped"]
    assert "= clean" in stress.format_table(ex)
    summary = stress.format_summary([res, ex])
    assert summary.splitlines()[0] == "| policy | clean | noise floor | score | mask_flip | latency |"
    expert_row = summary.splitlines()[-1].split(" | ")
    assert expert_row[3].endswith("(rows it meets)") and expert_row[4] == "="  # mask_flip cannot reach it


def test_a_partial_file_gives_back_the_chunks_it_was_given(tmp_path):
    path = tmp_path / "s.json.partial"
    r = {
        "success": np.array([True, False, True]),
        "final_distance": np.array([0.0123456789, 0.5, 1e-7], np.float32),
        "invalid": np.array([False, True, False]),
    }
    stress.Partial(path, "k").put("square/3", r)
    back = stress.Partial(path, "k")
    assert back.episodes() == 3 and back.get("square/0") is None
    for k, v in back.get("square/3").items():
        assert v.dtype == r[k].dtype and np.array_equal(v, r[k]), k  # bitwise, bools in their places
    path.write_text("[1, 2]")
    with pytest.raises(ConfigError, match="s.json.partial: not a stress partial file"):
        stress.Partial(path, "k")


def test_a_stopped_stress_run_resumes_from_its_partial_file_to_the_same_record(
    envs, encoder_file, monkeypatch, tmp_path
):
    from mjx_push import encoder as enc
    from mjx_push.train.networks import make_networks
    from mjx_push.train.runs.policies import Policy

    cfg = run_config(encoder_file)
    actor = make_networks(cfg.train.agent).init_actor(jax.random.PRNGKey(0), 3)
    policy = Policy(cfg, actor, enc.init_vae(jax.random.PRNGKey(1))["encoder"], {})
    sc = StressConfig(perturbations=("latency", "mask_flip"), levels=LEVELS, shapes=("square",), episodes=3, batch=B)
    whole = stress.stress(policy, sc)  # 4 cells x 3 episodes: 4 chunks of the batch

    partial = tmp_path / "stress.json.partial"
    done = []

    def stop_after_two(line):
        done.append(line)
        if len(done) == 2:
            raise KeyboardInterrupt  # a kill between chunks: the partial file holds two

    with pytest.raises(KeyboardInterrupt):
        stress.stress(policy, sc, progress=stop_after_two, resume_from=partial)
    assert len(json.loads(partial.read_text())["chunks"]) == 2
    calls = []
    run = stress.run_episodes
    monkeypatch.setattr(stress, "run_episodes", lambda *a: calls.append(a) or run(*a))
    resumed = stress.stress(policy, sc, resume_from=partial)
    assert len(calls) == 2 and resumed["resumed_episodes"] == 6  # only the missing chunks ran
    for key in ("rows", "score"):
        assert resumed[key] == whole[key], key
    # Another policy (or other settings) does not resume this file, and a broken file is named.
    other = Policy(cfg, jax.tree.map(lambda x: x + 1.0, actor), policy.encoder_params, {})
    with pytest.raises(ConfigError, match="holds a stress run of another policy or other settings"):
        stress.stress(other, sc, resume_from=partial)
    with pytest.raises(ConfigError, match="holds a stress run of another policy"):
        stress.stress(policy, dataclasses.replace(sc, seed=1), resume_from=partial)
    partial.write_text("{not json")
    with pytest.raises(ConfigError, match="stress.json.partial: not a readable stress partial file"):
        stress.stress(policy, sc, resume_from=partial)
    assert partial.read_text() == "{not json"  # refused, nothing overwritten


def test_stress_command_refuses_bad_options_by_name(capsys):
    from mjx_push.cli import main as cli_main

    for argv, message in [
        (["stress", "expert", "--levels", "extreme"], "--levels must be among"),
        (["stress", "expert", "--perturbations", "mask_flip", "nope"], "--perturbations must be among"),
        (["stress", "expert", "--episodes", "0"], "--episodes must be a positive integer"),
        (["stress", "runs/none", "--preset", "cpu"], "--preset chooses the scripted expert's action box"),
        (["stress", "runs/none"], "POLICY runs/none: no such file or directory"),
        (["deploy", "pretrained:egru", "--perturb", "nope"], "--perturb must be one of"),
    ]:
        assert cli_main(argv) == 2, argv
        assert message in capsys.readouterr().err, argv

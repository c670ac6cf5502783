"""The tiny eGRU run trained end to end on the MJX scene (the session fixture `tiny_egru_run`) and what is
done with it: what training stored, evaluation on shared seeds, the report, `mjx-push eval` and
`reproduce` (reuse, cached evaluations, teacher-free forks, CPU evaluation), and the tests that run
the run's own programs (later batches compile nothing; the rollout split over the host devices runs
one device's episodes). One file, so one worker trains the run and compiles its programs once: each
xdist worker that needs a session fixture computes it for itself."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import encoder as enc
from mjx_push.cli import main as cli_main
from mjx_push.train.comparison import report
from mjx_push.train.episodes import EvalSpec
from mjx_push.train.evaluate import evaluator_for
from mjx_push.train.push_task import make_push_adapter
from mjx_push.train.runs import policies
from mjx_push.train.runs.policies import Policy
from tests.helpers import renderer_or_skip


def test_egru_trains_on_the_pushing_scene(tiny_egru_run):
    cfg, d, summary, state = tiny_egru_run
    assert cfg.env.objects.mode == "improved"  # eGRU = GRU + improved force sampling
    # Warm-up ends with the first batch (12 steps), so both batches run 4 * 3 * 0.5 = 6 updates.
    assert summary["env_steps"] == 24 and summary["updates"] == 12
    data = jax.device_get(state.buffer.data)
    valid = data["valid"]
    assert valid.sum() == 8  # two batches of four episodes, none flagged invalid
    z = data["z_obj"][valid]  # latents of every step's mask, reset observation included
    assert np.isfinite(z).all() and z.shape[1:] == (4, 6)
    # Different objects give different latents; the goal's latent is the goal mask's.
    assert np.ptp(z[:, 0], axis=0).max() > 1e-4
    assert np.isfinite(jax.tree.leaves(state.sac.actor_params)[0]).all()
    policy = policies.load_policy(d / "best_policy")
    assert policy.config.agent == "egru"


# --- the run's own programs: compiled once, by this worker's fixture, reused here -----------------------
@pytest.fixture(scope="module")
def tiny_runner(tiny_egru_run):
    """A Runner of the tiny eGRU run's configuration as `run` builds it (so its programs are the
    fixture's), traced once for the tests below."""
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import DEFAULT_SUBSTEP_CHUNK

    cfg = tiny_egru_run[0]
    adapter = make_push_adapter(cfg.env, enc.load(cfg.encoder), DEFAULT_SUBSTEP_CHUNK, cfg.expert)
    return Runner(make_train(cfg.train, adapter))


def test_batches_after_the_first_compile_nothing_and_evaluate_the_protocols_episodes(tiny_egru_run, tiny_runner):
    """The tiny eGRU run's configuration as `run` builds it (so its programs are the fixture's): the
    environments are split over the host devices, yet the learner and the next rollout reuse the first
    batch's programs (argument placements that changed per batch once recompiled the rollout), and the
    in-run evaluation runs the protocol's episodes in their order. Whether an actor learns the expert's
    pushes on this scene: benchmarks/learning_checks.py (scene-imitation), run by CI."""
    from mjx_push.train.episodes import EvalSpec, episode_objects
    from mjx_push.train.push_task import EVAL_SHAPE

    cfg, runner = tiny_egru_run[0], tiny_runner
    state = runner.init(jax.random.PRNGKey(cfg.train.loop.seed))
    untrained = jax.tree.map(jnp.copy, state.sac.actor_params)
    compiles = []  # programs compiled (or loaded from the cache) after the first batch

    def on_event(event, secs, **kwargs):
        if ("backend_compile" in event and secs > 0.5) or "cache_retrieval" in event:
            compiles.append((event, round(secs, 2)))

    T = cfg.env.episode_length
    history = []
    for i in range(cfg.train.loop.num_iterations(T)):
        if i == 1:
            jax.monitoring.register_event_duration_secs_listener(on_event)
        state, m = runner.iteration(state)
        history.append(m)
    jax.monitoring.unregister_event_duration_listener(on_event)
    assert len(history) == 2 and bool(history[-1]["learning"])  # the second batch ran updates
    assert runner.trainer.rollout_split == ("groups" if len(jax.devices()) > 1 else None)
    assert compiles == [], compiles

    ev = runner.evaluate(untrained)
    loop = cfg.train.loop
    spec = EvalSpec(setting=loop.eval_setting, shape=EVAL_SHAPE[cfg.env.objects.shape], seed=loop.eval_seed)
    assert cfg.env.objects.shape == "any" and loop.eval_episodes == 2  # cuboid episode 0, cylinder episode 1
    want = [episode_objects(spec, cfg.env.objects, g, np.array([i]))[0] for i, g in enumerate(("box", "cylinder"))]
    start = [np.linalg.norm(w.start[0, :2] - w.goal[0, :2]) for w in want]
    np.testing.assert_allclose(ev["episode_start_distance"], start, rtol=1e-5)


def test_a_batch_split_over_the_devices_by_shape_groups_runs_one_devices_episodes(tiny_egru_run, tiny_runner):
    """A one-device run on two host devices runs each shape group of a batch as a program of its own
    on a device of its own (`make_group_collect`): its training episodes (expert and agent alike) and
    its evaluation episodes are those of the same batch run on one device, in the batch's order, to
    float rounding (the groups' programs are fused apart). Four environments: two cuboids on one device,
    two cylinders on the other."""
    from mjx_push.train.rollout import make_collect

    if len(jax.devices()) < 2:
        pytest.skip("one device: MJX_PUSH_CPU_DEVICES=1 or a one-core machine, nothing to split")
    cfg, runner = tiny_egru_run[0], tiny_runner  # its split rollout is the run's program
    assert cfg.train.loop.num_envs == 4
    params = enc.load(cfg.encoder)
    assert runner.trainer.rollout_mesh.size == 2 and runner.trainer.rollout_split == "groups"
    state = runner.init(jax.random.PRNGKey(1))
    one = make_push_adapter(cfg.env, params, expert_config=cfg.expert, max_devices=1)
    collect = make_collect(cfg.train, one, runner.trainer.networks)
    on_one = jax.jit(lambda p, k, e, ep: collect(p, k, 4, jnp.asarray(False), jnp.asarray(False), e, ep))
    expert = jnp.asarray([True, False, False, True])
    chunk = runner.eval_chunks()[0]
    for use in (False, True):  # training's fresh episodes, then the protocol's
        ep = {**chunk, "use": np.asarray(use)}
        split, split_stats = runner.rollout(state.sac.actor_params, jax.random.PRNGKey(5), False, False, expert, ep)
        whole, whole_stats = on_one(state.sac.actor_params, jax.random.PRNGKey(5), expert, ep)
        assert split.keys() == whole.keys() and split_stats.keys() == whole_stats.keys()
        for k in whole:
            np.testing.assert_allclose(np.asarray(split[k]), np.asarray(whole[k]), rtol=1e-5, atol=1e-6, err_msg=k)
        for k in whole_stats:
            want = np.asarray(whole_stats[k])
            np.testing.assert_allclose(np.asarray(split_stats[k]), want, rtol=1e-5, atol=1e-6, err_msg=k)
        np.testing.assert_array_equal(split["demo"], expert)
    assert not np.allclose(split["goal_xy"][0], split["goal_xy"][2])  # different episodes, not one repeated


# --- the evaluator on the trained policy --------------------------------------------------------------
@pytest.fixture(scope="module")
def evaluator(tiny_egru_run):
    cfg = tiny_egru_run[0]
    return evaluator_for(cfg.env, cfg.train.agent, 2)  # the CLI test below reuses its compiled episodes


def test_the_same_seeds_give_the_same_episodes_to_every_policy(tiny_egru_run, evaluator):
    cfg, d, _, state = tiny_egru_run
    trained = policies.load_policy(d / "best_policy")
    from mjx_push.train.networks import make_networks

    other_actor = make_networks(cfg.train.agent).init_actor(jax.random.PRNGKey(99), cfg.env.episode_length)
    other = Policy(cfg, other_actor, trained.encoder_params, {})
    spec = EvalSpec(setting="standard", shape="cylinder", episodes=3, batch=2, record=3)
    a, b = evaluator.evaluate(trained, spec), evaluator.evaluate(other, spec)
    for ra, rb in zip(a["recorded"], b["recorded"]):
        np.testing.assert_array_equal(ra["qpos"][0], rb["qpos"][0])  # same object, start, goal
        jax.tree.map(np.testing.assert_array_equal, ra["params"], rb["params"])
    assert not np.allclose(a["recorded"][0]["action"], b["recorded"][0]["action"])  # different policies
    # The distances: reset from the drawn start and goal (the same for both policies), end from the
    # object's last recorded pose; success is exactly "ends within tau".
    obj = evaluator.env("cylinder").ids.object_qpos
    for res in (a, b):
        per = res["per_episode"]
        for i, r in enumerate(res["recorded"]):
            goal = r["params"].goal[:2]
            assert per["start_distance"][i] == pytest.approx(np.linalg.norm(r["params"].start[:2] - goal), abs=1e-6)
            if not per["invalid"][i]:
                assert per["final_distance"][i] == pytest.approx(
                    np.linalg.norm(r["qpos"][-1][obj : obj + 2] - goal), abs=1e-6
                )
        np.testing.assert_array_equal(per["success"], (per["final_distance"] < 0.01) & ~per["invalid"])
    np.testing.assert_array_equal(a["per_episode"]["start_distance"], b["per_episode"]["start_distance"])
    # Episodes do not depend on the batch they were simulated in.
    p2, _ = evaluator.episode_params(spec, "cylinder", np.array([0, 1, 2]))
    p1, _ = evaluator.episode_params(spec, "cylinder", np.array([2]))
    np.testing.assert_array_equal(np.asarray(p2.goal[2]), np.asarray(p1.goal[0]))
    assert a["summary"]["success"]["n"] == 3


def test_report_end_to_end_from_a_trained_checkpoint(tiny_egru_run, evaluator, tmp_path):
    cfg, d, _, _ = tiny_egru_run
    policy = policies.load_policy(d / "best_policy")
    results = {}
    for agent in ("egru", "vpm"):  # the same policy under two names: the report's layout, not a comparison
        results[agent] = {}
        for shape in ("cylinder",):
            res = evaluator.evaluate(policy, EvalSpec(setting="difficult", shape=shape, episodes=2, batch=2))
            results[agent][shape] = [res["summary"]]
    path = report.write_report(
        tmp_path, results, {"budget": "smoke", "seeds": 1, "episodes": 2, "setting": "difficult", "wall_s": 1.0}
    )
    text = path.read_text()
    assert "| cylinder | eGRU |" in text and "| cylinder | VPM |" in text
    d = results["egru"]["cylinder"][0]
    assert f"{100 * d['start_distance']['mean']:.1f} -> {100 * d['final_distance']['mean']:.1f}" in text
    assert (tmp_path / "metrics.png").stat().st_size > 10_000
    assert (tmp_path / "friction_force.png").stat().st_size > 10_000
    combined = json.loads((tmp_path / "results.json").read_text())["combined"]
    assert combined["egru"]["cylinder"]["success"]["n_episodes"] == 2


@pytest.mark.renderer
def test_eval_cli_writes_json_and_a_video(tiny_egru_run, tmp_path):
    renderer_or_skip()  # fails instead under MJX_PUSH_REQUIRE_RENDERER=1 (CI)
    _, d, _, _ = tiny_egru_run
    out = tmp_path / "eval.json"
    gif = tmp_path / "episodes.gif"
    assert (
        cli_main(
            [
                "eval",
                str(d),
                "--episodes",
                "2",
                "--batch",
                "2",
                "--shape",
                "cylinder",
                "--setting",
                "standard",
                "--out",
                str(out),
                "--video",
                str(gif),
                "--video-episodes",
                "1",
                "--cpu",
                "analytic",
                "render",
            ]
        )
        == 0
    )
    rec = json.loads(out.read_text())
    assert set(rec["summary"]) == {"success", "reward", "overshoot", "distance", "start_distance", "final_distance"}
    assert len(rec["per_episode"]["reward"]) == 2
    # --cpu: the same episodes in CPU MuJoCo per mask source, with their agreement with the MJX run.
    assert set(rec["cpu"]) == {"analytic", "render"}
    for source, cpu in rec["cpu"].items():
        starts = [r["start_distance"] for r in cpu["episodes"]]
        np.testing.assert_allclose(starts, rec["per_episode"]["start_distance"], atol=1e-5, err_msg=source)
        a = cpu["agreement"]["all"]
        assert set(cpu["agreement"]) == {"all", "cylinders"} and a["episodes"] == 2
        assert a["mjx_success"] == pytest.approx(rec["summary"]["success"]["mean"])
        assert a["cpu_success"] == pytest.approx(cpu["summary"]["success"]["mean"])
    import imageio.v2 as imageio

    frames = imageio.mimread(gif)
    assert len(frames) == 4  # reset + 3 steps of the tiny episode
    assert frames[0].shape[1] == 2 * frames[0].shape[0] * 320 // 240  # two views side by side


def _reproduce_tiny(out, cfg, agents=("egru",), teacher_free=None, report_only=False) -> str:
    """`reproduce` with every agent at the tiny run's configuration `cfg`: cylinders only, 2 episodes, no
    expert row (tests/test_expert.py has it). Returns its log."""
    from mjx_push.train.comparison import reproduce as rep
    from mjx_push.train.comparison.study import Study

    lines: list[str] = []
    study = Study(
        "smoke",
        out,
        episodes=2,
        agents=agents,
        shapes=("cylinder",),
        teacher_free=teacher_free,
        config_hook=lambda _: cfg,
    )
    rep.reproduce(study, log=lines.append, expert=False, report_only=report_only)
    return "\n".join(lines)


def test_reproduce_reuses_the_run_and_caches_each_evaluation(tiny_egru_run, evaluator, tmp_path):
    import shutil

    from mjx_push.train.comparison import reproduce as rep
    from mjx_push.train.comparison.cache import policy_fingerprint, scored_policy
    from mjx_push.train.comparison.study import Study
    from mjx_push.train.networks import make_networks

    cfg, d, _, _ = tiny_egru_run
    out = tmp_path / "repro"
    run_dir = out / "runs" / "egru-s0"
    shutil.copytree(d, run_dir)

    def go():
        log = _reproduce_tiny(out, cfg)
        return log, json.loads((out / "results.json").read_text())["combined"]["egru"]["cylinder"]

    log, first = go()
    assert "reusing finished run" in log and "reusing evaluation" not in log
    cache = run_dir / "eval-difficult-cylinder-2.json"
    rec = json.loads(cache.read_text())
    name, step = scored_policy(run_dir)
    assert rec["policy"] == name and rec["policy_env_steps"] == step
    assert rec["policy_sha256"] == policy_fingerprint(run_dir / name) and len(rec["per_episode"]["reward"]) == 2
    text = (out / "report.md").read_text()
    assert "| cylinder | eGRU |" in text
    # The training section comes from the run's metrics.csv: its evaluations and its cost.
    training, batch = report.read_training(run_dir), cfg.train.loop.eval_every_env_steps  # two batches
    assert training["eval_env_steps"] == [batch, 2 * batch] and training["env_steps"] == 2 * batch
    assert training["wall_s"] > 0
    assert f"| eGRU | 1 | {2 * batch} | {training['updates']:,} |" in text and f"| {step:,} |" in text
    assert (out / "learning_curves.png").stat().st_size > 10_000

    log, again = go()
    assert "reusing evaluation" in log and again == first, (again, first)

    stale = dict(rec, per_episode={k: v for k, v in rec["per_episode"].items() if k != "start_distance"})
    cache.write_text(json.dumps(stale))  # a cache from before the distances were recorded
    log, _ = go()
    assert "reusing evaluation" not in log and "start_distance" in json.loads(cache.read_text())["per_episode"]

    cache.write_text("{ truncated")  # a damaged cache is recomputed, not trusted
    log, _ = go()
    assert "reusing evaluation" not in log and json.loads(cache.read_text())["summary"] == rec["summary"]

    # The report from whatever has finished: the eGRU run (its evaluation reused), not the absent VPM run.
    lines = _reproduce_tiny(out, cfg, agents=("egru", "vpm"), report_only=True).splitlines()
    assert "reusing evaluation" in "\n".join(lines)
    assert f"{out / 'runs' / 'vpm-s0'} has not finished: left out of the report" in lines
    results = json.loads((out / "results.json").read_text())
    assert list(results["combined"]) == ["egru"] and results["meta"]["missing_runs"] == ["vpm-s0"]
    assert "Not finished when this report was built, so not in it: vpm-s0." in (out / "report.md").read_text()
    with pytest.raises(ValueError, match="no finished run"):
        rep.reproduce(Study("smoke", tmp_path / "empty", episodes=2, agents=("vpm",)), report_only=True, expert=False)

    # New weights under the same name: the cached evaluation no longer belongs to them.
    policy = policies.load_policy(run_dir / name)
    other = make_networks(cfg.train.agent).init_actor(jax.random.PRNGKey(7), cfg.env.episode_length)
    policies.save_policy(run_dir / name, cfg, other, policy.encoder_params, policy.scores)
    log, _ = go()
    assert "reusing evaluation" not in log
    assert json.loads(cache.read_text())["policy_sha256"] != rec["policy_sha256"]


def test_reproduce_teacher_free_forks_each_finished_run_and_reports_the_forks(
    tiny_egru_run, evaluator, tmp_path, monkeypatch
):
    """--teacher-free N: the finished budget run is forked at its end with the teacher-free
    configuration; the report in OUT/teacher-free scores the fork, the budget's run is only read, and a
    second call reuses the fork and its evaluation. The fork's training is stood in for by a copy of
    the run (a real fork costs a compilation here; tests/test_run.py trains real forks)."""
    import shutil

    from mjx_push.train import presets
    from mjx_push.train.comparison.study import teacher_free_config
    from mjx_push.train.runs import run as run_mod
    from mjx_push.train.runs.fork import ForkSource

    cfg, d, _, _ = tiny_egru_run
    out = tmp_path / "repro"
    base = out / "runs" / "egru-s0"
    shutil.copytree(d, base)
    base_files = sorted(p.name for p in base.iterdir())
    calls = []

    def fake_fork(c, run_dir, resume, fork=None):
        calls.append((c, run_dir, resume, fork))
        shutil.copytree(fork.run_dir, run_dir)
        (run_dir / "config.json").write_text(json.dumps(presets.config_dict(c)))

    monkeypatch.setattr(run_mod, "run", fake_fork)

    end, tf = cfg.train.loop.total_env_steps, 6  # the run's end; the teacher annealed over tf / 2

    def go(**kw):
        return _reproduce_tiny(out, cfg, teacher_free=tf, **kw)

    log = go()
    fork = out / "teacher-free" / "runs" / "egru-s0"
    assert calls == [(teacher_free_config(cfg, tf), fork, False, ForkSource(base))]
    assert f"reusing finished run {base}" in log and f"forking {base} at its last checkpoint into {fork}" in log
    assert (fork / "eval-difficult-cylinder-2.json").is_file() and not (
        base / "eval-difficult-cylinder-2.json"
    ).exists()
    assert sorted(p.name for p in base.iterdir()) == base_files
    results = json.loads((out / "teacher-free" / "results.json").read_text())
    assert results["meta"]["teacher_free"] == tf
    assert results["meta"]["teacher_free_env_steps"] == [end, end + tf // 2, end + tf]
    assert list(results["combined"]) == ["egru"]
    text = " ".join((out / "teacher-free" / "report.md").read_text().split())  # wrapped lines joined
    assert f"--teacher-free {tf}" in text and f"between {end} and {end + tf // 2} env steps" in text
    assert "| cylinder | eGRU |" in text
    assert not (out / "report.md").exists()  # the plain comparison's report is not written over

    log = go()
    assert len(calls) == 1 and f"reusing finished run {fork}" in log and "reusing evaluation" in log
    log = go(report_only=True)
    assert "reusing evaluation" in log
    shutil.rmtree(fork)
    with pytest.raises(ValueError, match="no finished run in .*teacher-free"):
        go(report_only=True)


def test_reproduce_cpu_evaluates_each_run_on_its_mjx_episodes_and_caches_it(tiny_egru_run, evaluator, tmp_path):
    import shutil

    from mjx_push.export.report_parity import cpu_evaluation, parity_report
    from mjx_push.train.comparison import reproduce as rep
    from mjx_push.train.comparison.study import Study

    cfg, d, _, _ = tiny_egru_run
    out = tmp_path / "repro"
    run_dir = out / "runs" / "egru-s0"
    shutil.copytree(d, run_dir)
    total = cfg.train.loop.total_env_steps
    # The tiny run's length, so the parity report counts it as finished (the hook is the tests' only).
    study = Study("smoke", out, episodes=2, shapes=("cylinder",), total_env_steps=total, config_hook=lambda _: cfg)
    rep.agent_job(study, "egru", 0, train=False)
    mjx = json.loads((run_dir / "eval-difficult-cylinder-2.json").read_text())
    lines: list[str] = []
    path = parity_report(study, [("egru", 0), ("vpm", 0)], ("analytic",), lines.append)
    cpu = json.loads((run_dir / "eval-cpu-analytic-difficult-cylinder-2.json").read_text())
    # The CPU run meets the MJX evaluation's episodes, and its agreement reads both runs' outcomes.
    np.testing.assert_allclose(
        [r["start_distance"] for r in cpu["records"]], mjx["per_episode"]["start_distance"], atol=1e-5
    )
    a = cpu["agreement"]["all"]
    assert a["episodes"] == 2 and a["mjx_success"] == pytest.approx(mjx["summary"]["success"]["mean"])
    assert a["cpu_success"] == pytest.approx(cpu["summary"]["success"]["mean"])
    text = path.read_text()
    assert "| cylinder | eGRU | analytic |" in text and "Not finished, so not in this table: vpm-s0." in text
    assert not any("reusing" in line for line in lines)
    lines.clear()
    cpu_evaluation(run_dir, "difficult", "cylinder", 2, "analytic", lines.append)
    assert any("reusing evaluation" in line for line in lines)
    with pytest.raises(ValueError, match="no MJX evaluation to compare with"):
        cpu_evaluation(run_dir, "difficult", "square", 2, "analytic")
    with pytest.raises(ValueError, match="no finished run"):
        parity_report(study, [("vpm", 0)], ("analytic",))
    with pytest.raises(ValueError, match="no finished run"):  # a total the run has not been trained to
        parity_report(dataclasses.replace(study, total_env_steps=total + 1), [("egru", 0)], ("analytic",))

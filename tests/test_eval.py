"""The evaluation protocol (train/evaluate.py), the report (train/comparison/report.py) and `mjx-push eval`."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import json
import shlex
import math

import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import scene
from tests.helpers import B, HOME_XY, a_s_for, action_for, make_params
from mjx_push.train.comparison import report
from mjx_push.cli import main as cli_main
from mjx_push.train.evaluate import sem, summarize
from mjx_push.train.episodes import EvalSpec


# --- arithmetic ---------------------------------------------------------------------------------------
def test_sem_is_the_sample_std_over_sqrt_n():
    assert sem([1.0, 2.0, 3.0, 4.0]) == pytest.approx(math.sqrt(5 / 3) / 2)
    assert sem([0.0, 0.0, 1.0, 1.0]) == pytest.approx(math.sqrt(1 / 3) / 2)
    assert sem([7.0]) == 0.0
    s = summarize(
        {"success": [1, 0, 1, 1], "reward": [-3, -50, 0, -1], "overshoot": [0, 0, 0, 0], "distance": [2, 1, 0, 1]}
    )
    assert s["success"] == {"mean": 0.75, "sem": pytest.approx(0.25), "n": 4}
    assert s["reward"]["mean"] == -13.5 and s["overshoot"]["sem"] == 0.0


def test_seeds_combine_with_the_sem_across_seed_means():
    per_seed = [
        summarize({"success": [1, 1], "reward": [0, 0], "overshoot": [1, 1], "distance": [0, 2]}),
        summarize({"success": [0, 1], "reward": [-50, 0], "overshoot": [0, 0], "distance": [1, 1]}),
    ]
    c = report.combine(per_seed)
    assert c["success"]["mean"] == 0.75 and c["success"]["sem"] == pytest.approx(sem([1.0, 0.5]))
    assert c["reward"]["n_episodes"] == 4 and c["reward"]["n_seeds"] == 2
    one = report.combine(per_seed[:1])
    assert one["distance"]["sem"] == pytest.approx(sem([0, 2]))  # one seed: the SEM over episodes


# --- bad input ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(setting="hard"), "setting must be one of"),
        (dict(shape="sphere"), "shape must be one of"),
        (dict(episodes=0), "episodes must be a positive integer"),
        (dict(mass=(0.1, 0.2)), "need setting 'custom'"),
    ],
)
def test_bad_evaluation_settings_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        EvalSpec(**kwargs)


def test_eval_cli_reports_bad_input_in_the_users_words(tmp_path, capsys):
    missing = tmp_path / "missing-run"
    assert cli_main(["eval", str(missing)]) == 2
    err = capsys.readouterr().err
    assert f"POLICY {missing}: no such file or directory" in err and "missing-run.msgpack" not in err
    assert cli_main(["eval", str(tmp_path)]) == 2
    assert "not a finished run directory" in capsys.readouterr().err
    assert cli_main(["eval", str(tmp_path), "--episodes", "0"]) == 2
    assert "--episodes must be a positive integer" in capsys.readouterr().err
    assert cli_main(["eval", str(tmp_path), "--mass", "0.1", "0.2"]) == 2
    assert "--mass needs --setting custom" in capsys.readouterr().err
    assert cli_main(["eval", str(tmp_path), "--setting", "custom", "--mass", "0.5", "0.1"]) == 2
    assert "--mass must satisfy" in capsys.readouterr().err
    assert cli_main(["eval", str(tmp_path), "--video", str(tmp_path / "v.avi")]) == 2
    assert "--video" in capsys.readouterr().err
    assert cli_main(["eval", "expert", "--cpu", "analytic"]) == 2
    assert "the scripted expert has none" in capsys.readouterr().err
    assert cli_main(["eval", str(tmp_path), "--cpu", "analytic", "analytic"]) == 2
    assert "--cpu lists a mask source twice" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["eval", str(tmp_path), "--shape", "sphere"])
    with pytest.raises(SystemExit):
        cli_main(["eval", str(tmp_path), "--cpu", "camera"])


def test_eval_and_deploy_share_options_and_defaults():
    import dataclasses as dc

    from mjx_push.cli import Deploy
    from mjx_push.cli import Eval
    from mjx_push.cli.options import EvalOptions

    shared = {f.name: (f.type, f.default) for f in dc.fields(EvalOptions)}
    for cmd in (Eval, Deploy):
        assert {f.name: (f.type, f.default) for f in dc.fields(cmd) if f.name in shared} == shared, cmd
    spec = EvalOptions().spec()
    assert (spec.setting, spec.shape, spec.seed) == (EvalSpec().setting, EvalSpec().shape, EvalSpec().seed)


def test_custom_and_difficult_settings_draw_their_ranges():
    spec = EvalSpec(setting="custom", mass=(0.3, 0.4), friction=(0.5, 0.6), min_height=0.05)
    cfg = spec.object_config()
    assert (cfg.mass, cfg.friction, cfg.min_height, cfg.mode) == ((0.3, 0.4), (0.5, 0.6), 0.05, "uniform")
    hard = EvalSpec(setting="difficult").object_config()
    assert (hard.mass, hard.friction, hard.min_height) == ((0.001, 0.01), (0.2, 0.3), 0.052)


# --- scripted episodes with known answers -------------------------------------------------------------
def test_scripted_pushes_give_the_known_correction_counts(box_sim):
    """Four boxes: a rod that never moves (no correction, reward -steps), one that pushes the object
    straight through its goal (one overshoot, no distance correction), one
    that pushes it exactly onto the goal region and stops (success), and one with the goal at the start
    (success from the first step, no correction)."""
    start, goal = (0.1, 0.0, 0.0), (0.15, 0.0, 0.0)
    # Env 1's goal is 2 cm ahead and the push aims 13 cm further, so the object leaves the disc fast: an
    # exit counts only when its substep jumps more than eps = 2e-5 m past tau (docs/task.md section 7); a slow
    # exit (under ~0.04 m/s) may go uncounted.
    params = [
        make_params("box", sides=(0.06, 0.06), start=start, goal=goal),
        make_params("box", sides=(0.06, 0.06), start=start, goal=(0.12, 0.0, 0.0)),
        make_params("box", sides=(0.06, 0.06), start=start, goal=(0.115, 0.0, 0.0)),
        make_params("box", sides=(0.06, 0.06), start=start, goal=start),
    ]
    s = box_sim.start(params)
    rod_r = scene.ROD_RADIUS  # contact when the rod's axis is 3 cm + r behind the box centre
    # Flange x targets (relative to home) per env: stay; push the object's centre to 0.25 (past 0.12);
    # push it to about 0.115 (inside the 1 cm goal radius around 0.115); stay.
    back = [0.0, 0.25 - 0.03 - rod_r, 0.115 - 0.03 - rod_r, 0.0]
    steps = 8
    rewards = np.zeros(B)
    for _ in range(steps):
        ee = s.pipeline_state.site_xpos[:, box_sim.env.ids.flange_site, :2]
        target = jnp.stack([HOME_XY[0] + jnp.asarray(back), jnp.full(B, HOME_XY[1])], axis=1)
        s = box_sim.step(s, action_for(ee, target, a_s_for(600)))
        rewards += np.asarray(s.reward)
    c = s.info["corrections"]
    dist = np.linalg.norm(np.asarray(s.info["object_xy"] - s.info["goal_xy"]), axis=1)
    assert not np.asarray(s.info["episode_invalid"]).any()
    # Never moves.
    assert dist[0] == pytest.approx(0.05, abs=1e-3) and rewards[0] == -steps
    assert int(c.overshoot[0]) == 0 and int(c.distance[0]) == 0
    # Pushed through the goal: enters the 1 cm disc once and leaves it once; the distance only falls
    # and then only grows, so no distance correction.
    assert dist[1] > 0.05
    assert int(c.overshoot[1]) == 1 and int(c.distance[1]) == 0
    # Pushed onto the goal: success, no overshoot.
    assert dist[2] < 0.01 and int(c.overshoot[2]) == 0 and rewards[2] > -steps
    # Already at the goal: every step rewarded 0.
    assert rewards[3] == 0 and int(c.overshoot[3]) == 0 and int(c.distance[3]) == 0


# --- the report ---------------------------------------------------------------------------------------
def test_read_training_names_a_directory_without_metrics(tmp_path):
    with pytest.raises(ValueError, match="no metrics.csv"):
        report.read_training(tmp_path)


def test_friction_force_samplers_differ_as_in_the_paper():
    f = report.friction_force_samples(n=20_000)
    # Improved sampling puts more mass on the smallest and far more on the largest forces than uniform
    # m * mu does (half its draws sit near each end of [F_min, F_max]).
    g = 9.81
    lo, hi = 0.001 * 0.2 * g, 1.0 * 1.0 * g
    for v in f.values():
        assert v.min() >= lo * 0.999 and v.max() <= hi * 1.001
    small = 0.01 * hi
    assert np.mean(f["improved"] < small) > 1.3 * np.mean(f["uniform"] < small)
    assert np.mean(f["improved"] > 0.8 * hi) > 5 * np.mean(f["uniform"] > 0.8 * hi)


def test_friction_force_samples_are_drawn_once_per_process_and_cannot_be_changed(monkeypatch):
    """Every report draws the figure's samples; a second report reuses the first's draws."""
    from mjx_push import objects

    calls = []
    sample = objects.sample
    monkeypatch.setattr(objects, "sample", lambda *a: calls.append(1) or sample(*a))
    first = report.friction_force_samples(n=64, seed=5)
    assert len(calls) == 2  # traced once per sampler
    again = report.friction_force_samples(n=64, seed=5)
    assert len(calls) == 2 and all(again[k] is first[k] for k in first)
    with pytest.raises(ValueError, match="read-only"):
        again["uniform"][0] = 0.0
    again.pop("uniform")  # the caller's dict, not the cache's
    assert set(report.friction_force_samples(n=64, seed=5)) == {"uniform", "improved"}
    report.friction_force_samples(n=64, seed=6)
    assert len(calls) == 4  # another seed is drawn


# --- reproduce: reuse, cached evaluations, worker processes -------------------------------------------
def test_teacher_free_config_anneals_after_the_budget_and_refuses_what_it_cannot_anneal(tmp_path, capsys):
    from mjx_push.train import configio, presets
    from mjx_push.train.comparison import reproduce as rep
    from mjx_push.train.comparison.study import Study, budget_config, teacher_free_config

    cfg = budget_config("cpu-long", "egru", 1)
    tf = teacher_free_config(cfg, 32000)  # docs/learners.md's recipe, from the budget's own end
    assert sorted(configio.differences(presets.config_dict(cfg), presets.config_dict(tf))) == [
        "train.demo.anneal_end: None != 80000",
        "train.demo.anneal_start: None != 64000",
        "train.loop.total_env_steps: 64000 != 96000",
        f"train.sac.anchor_weight: 0.0 != {cfg.train.sac.bc_weight}",
    ]
    assert tf.train.demo.teacher_scale(80000) == 0 and tf.train.demo.teacher_scale(64000) == 1
    study = Study("cpu-long", tmp_path, agents=("vpm",), teacher_free=32000)
    assert study.job_config("vpm", 2) == (
        teacher_free_config(budget_config("cpu-long", "vpm", 2), 32000),
        tmp_path / "teacher-free" / "runs" / "vpm-s2",
    )
    assert study.run_dir("vpm", 2) == tmp_path / "runs" / "vpm-s2"  # the budget's run, forked
    line = rep.plan(study)[0]
    assert line == f"mjx-push reproduce --budget cpu-long --out {tmp_path} --teacher-free 32000 --job vpm:0"
    args = ["reproduce", "--budget", "cpu-long", "--plan", str(tmp_path / "p.txt"), "--teacher-free"]
    for bad, says in (
        (["1"], "must be >= 2 env steps"),
        (
            ["32000", "--set", "train.sac.bc_weight=0", "train.demo.fraction=0", "train.demo.warmup=false"],
            "without a teacher",
        ),
        (
            ["32000", "--set", "train.demo.anneal_start=50000", "train.demo.anneal_end=60000"],
            "leave train.demo.anneal_start",
        ),
    ):
        assert cli_main([*args, *bad]) == 2
        assert says in capsys.readouterr().err, bad
    assert not (tmp_path / "p.txt").exists()


def test_scored_policy_replays_the_selection_rule_over_the_runs_evaluations(tmp_path):
    """A run trained under the old strict tie rule saved its first of several tied actors as best; the
    table must score the actor the current rule keeps (the final one), and say so when none holds it."""
    from mjx_push.train.comparison.cache import scored_policy

    cols = "env_steps,iteration_s,updates,eval/mean_reward,eval/success_rate\n"

    def run(rows: str, best_step: int, final_step: int | None):
        d = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
        d.mkdir()
        (d / "metrics.csv").write_text(cols + rows)
        (d / "best_policy.json").write_text(json.dumps({"scores": {"best_env_steps": best_step}}))
        if final_step is not None:
            (d / "final_policy.json").write_text(json.dumps({"scores": {"env_steps": final_step}}))
        return d

    tied = "5,1,0,-50.0,0.0\n8,1,3,,\n10,1,5,-50.0,0.0\n15,1,10,-50.0,0.0\n"
    assert scored_policy(run(tied, best_step=5, final_step=15)) == ("final_policy", 15)  # old rule's file
    assert scored_policy(run(tied, best_step=15, final_step=15)) == ("best_policy", 15)
    better_early = "5,1,0,-40.0,0.1\n10,1,5,-50.0,0.0\n15,1,10,-45.0,0.0\n"
    assert scored_policy(run(better_early, best_step=5, final_step=15)) == ("best_policy", 5)
    # A tie with a lower success rate keeps the older actor.
    assert scored_policy(run("5,1,0,-45.0,0.2\n15,1,10,-45.0,0.1\n", 5, 15)) == ("best_policy", 5)
    with pytest.raises(ValueError, match="env step 10"):
        scored_policy(run("5,1,0,-50.0,0.0\n10,1,5,-40.0,0.1\n15,1,10,-45.0,0.0\n", 5, 15))
    with pytest.raises(ValueError, match="no evaluation"):
        scored_policy(run("5,1,0,,\n", 5, None))


def test_run_jobs_uses_worker_processes_keeps_order_and_names_a_failure():
    import os

    from tests.job_fns import pid_and_square
    from mjx_push.train.comparison.jobs import run_jobs

    calls = [((x,), {}) for x in (3, 1, 2)]
    out = run_jobs(pid_and_square, calls, jobs=2)
    assert [sq for _, sq in out] == [9, 1, 4]
    assert all(pid != os.getpid() for pid, _ in out)
    assert run_jobs(pid_and_square, calls, jobs=1) == [(os.getpid(), 9), (os.getpid(), 1), (os.getpid(), 4)]
    with pytest.raises(RuntimeError, match=r"job \(-1,\) failed: ValueError: negative input -1"):
        run_jobs(pid_and_square, [((2,), {}), ((-1,), {})], jobs=2)
    with pytest.raises(ValueError, match="jobs must be >= 1"):
        run_jobs(pid_and_square, calls, jobs=0)


def test_reproduce_plan_lists_one_command_per_job_then_the_report(tmp_path, capsys):
    from mjx_push.train.comparison import reproduce as rep
    from mjx_push.train.comparison.study import Study

    # The lines themselves: tests/test_comparison_study.py. Here: the command writes exactly them.
    lines = rep.plan(Study("cpu-long", tmp_path, seeds=2, agents=("vpm", "egru")))
    assert len(lines) == 2 * 2 + 2 and lines[-1].endswith("--report-only")
    plan_file = tmp_path / "plan.txt"
    assert (
        cli_main(
            [
                "reproduce",
                "--budget",
                "cpu-long",
                "--seeds",
                "2",
                "--agents",
                "vpm",
                "egru",
                "--out",
                str(tmp_path),
                "--plan",
                str(plan_file),
            ]
        )
        == 0
    )
    assert plan_file.read_text().splitlines() == lines
    assert cli_main(["reproduce", "--job", "dqn:0"]) == 2
    assert "--job must be AGENT:SEED" in capsys.readouterr().err
    assert cli_main(["reproduce", "--job", "vpm:0", "--report-only"]) == 2
    assert "exclude each other" in capsys.readouterr().err


def test_reproduce_restarts_a_run_killed_before_its_first_checkpoint(tmp_path, monkeypatch):
    """A run stopped in its first batches (logs, no checkpoint) has nothing to resume: reproduce starts
    it again instead of failing on a directory that "already holds a run"."""
    from mjx_push.train import presets
    from mjx_push.train.comparison import reproduce as rep
    from mjx_push.train.runs import run as run_mod

    cfg = presets.make("vpm", "smoke")
    run_dir = tmp_path / "runs" / "vpm-s0"
    (run_dir / "checkpoints").mkdir(parents=True)
    (run_dir / "metrics.csv").write_text("env_steps\n400\n")
    calls = []
    monkeypatch.setattr(run_mod, "run", lambda c, d, resume: calls.append((d, resume, sorted(d.glob("*")))))
    lines: list[str] = []
    rep.train_or_reuse(cfg, run_dir, lines.append)
    assert calls == [(run_dir, False, [])] and "stopped before its first checkpoint" in lines[0]


def test_reproduce_cpu_refuses_what_it_cannot_evaluate(tmp_path, capsys):
    assert cli_main(["reproduce", "--plan", str(tmp_path / "plan.txt"), "--cpu", "analytic"]) == 2
    assert "--cpu evaluates trained agents: not with --plan or --job expert" in capsys.readouterr().err
    assert cli_main(["reproduce", "--cpu", "render", "render"]) == 2
    assert "--cpu lists a mask source twice" in capsys.readouterr().err
    assert not (tmp_path / "plan.txt").exists()


def test_reproduce_set_changes_every_agent_and_the_expert_and_its_plan_carries_it(tmp_path, capsys):
    """`reproduce --set`: the comparison under a variant. Every agent's configuration and the expert's
    take the override, the plan's commands repeat it, and a bad one is refused before any work."""
    from mjx_push.train import presets
    from mjx_push.train.comparison import reproduce as rep
    from mjx_push.train.comparison.study import AGENTS, Study, budget_config

    overrides = presets.parse_overrides(["expert.hold_short=true", "env.substeps=[10,600]"])
    for agent in AGENTS:
        cfg = budget_config("cpu-long", agent, 1, overrides=overrides)
        assert cfg.expert.hold_short is True and cfg.env.substeps == (10, 600) and cfg.train.agent.kind == agent
        assert Study("cpu-long", tmp_path, overrides=overrides).config(agent, 1) == cfg
    assert not budget_config("cpu-long", "vpm", 0).expert.hold_short  # the budget's own expert otherwise
    line = rep.plan(Study("cpu-long", tmp_path, agents=("vpm",), overrides=overrides))[0]
    assert line.endswith(" --set expert.hold_short=true 'env.substeps=[10,600]' --job vpm:0")
    assert presets.parse_overrides(shlex.split(line.split(" --set ")[1])[:-2]) == overrides  # round trip
    plan_file = tmp_path / "plan.txt"
    args = ["reproduce", "--budget", "cpu-long", "--out", str(tmp_path), "--plan", str(plan_file)]
    assert cli_main([*args, "--set", "expert.hold_short=true"]) == 0
    assert all("--set expert.hold_short=true" in cmd for cmd in plan_file.read_text().splitlines())
    for bad, says in (("expert.hold_shrt=false", "no field 'hold_shrt'"), ("train.sac.lr=abc", "must be a number")):
        assert cli_main([*args, "--set", bad]) == 2
        assert says in capsys.readouterr().err, bad


def test_reproduce_trains_a_finished_run_of_a_smaller_budget_longer(tmp_path, monkeypatch, capsys):
    """--total-env-steps above a finished run's: reproduce resumes that run for the longer total (the
    run itself: tests/test_run.py), reports only runs of that total, and its plan carries the flag."""
    from mjx_push.train import presets
    from mjx_push.train.comparison import reproduce as rep
    from mjx_push.train.comparison.study import Study, budget_config
    from mjx_push.train.runs import run as run_mod

    cfg = presets.make("vpm", "smoke")
    run_dir = tmp_path / "runs" / "vpm-s0"
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(json.dumps(presets.config_dict(cfg)))
    (run_dir / "summary.json").write_text("{}")
    (run_dir / "best_policy.msgpack").write_bytes(b"")
    total = cfg.train.loop.total_env_steps
    longer = budget_config("smoke", "vpm", 0, 2 * total)
    assert longer.train.loop.total_env_steps == 2 * total
    assert rep.is_finished(run_dir) and rep.is_finished(run_dir, total) and not rep.is_finished(run_dir, 2 * total)
    calls = []
    monkeypatch.setattr(run_mod, "run", lambda c, d, resume: calls.append((c, d, resume)))
    lines: list[str] = []
    rep.train_or_reuse(longer, run_dir, lines.append)
    assert calls == [(longer, run_dir, True)] and f"longer: {2 * total:,} env steps" in lines[0]
    other = presets.with_overrides(longer, {"train.sac.lr": 3e-4})
    with pytest.raises(ValueError, match="another configuration"):
        rep.train_or_reuse(other, run_dir, lines.append)
    study = Study("smoke", tmp_path, episodes=2, agents=("vpm",), total_env_steps=2 * total)
    with pytest.raises(ValueError, match="no finished run"):  # the run has not been trained longer yet
        rep.reproduce(study, report_only=True, expert=False)
    assert rep.plan(Study("cpu-long", tmp_path, agents=("vpm",), total_env_steps=128000))[0] == (
        f"mjx-push reproduce --budget cpu-long --out {tmp_path} --total-env-steps 128000 --job vpm:0"
    )
    assert cli_main(["reproduce", "--total-env-steps", "0", "--plan", str(tmp_path / "p.txt")]) == 2
    assert "--total-env-steps must be" in capsys.readouterr().err

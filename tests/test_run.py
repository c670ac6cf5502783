"""Training runs on disk (train/runs/run.py) on the toy task: exact resume from orbax checkpoints, clear
errors for corrupt or mismatched checkpoints and policies, logs and saved policies."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import csv
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from mjx_push.train.runs import run as run_mod
from mjx_push.train.runs import checkpoints
from mjx_push.train.runs import policies
from mjx_push.cli import main as cli_main
from mjx_push.train.runs.fork import check_fork
from tests.toy import make_toy

from tests.helpers import TOY_TAU as TAU
from tests.helpers import latest_state, toy_run_config


@pytest.fixture(scope="module")
def toy():
    return make_toy(success_tau=TAU)


@pytest.fixture(scope="module")
def full_run(tmp_path_factory, toy, encoder_file):
    cfg = toy_run_config(encoder_file)
    d = tmp_path_factory.mktemp("full")
    summary, state = run_mod.run(cfg, d, adapter=toy, checkpoint_every=2)
    return cfg, d, summary, jax.device_get(state)


def test_killed_and_resumed_run_equals_an_uninterrupted_one(full_run, tmp_path, toy):
    cfg, _, _, full_state = full_run
    d = tmp_path / "resumed"
    partial, partial_state = run_mod.run(cfg, d, adapter=toy, checkpoint_every=1, stop_after=3)
    assert partial["stopped_at_env_steps"] == 120
    # Reopen from disk, as a new process would: only the checkpoint carries the state over.
    summary, state = run_mod.run(cfg, d, adapter=toy, resume=True)
    assert summary["resumed_from_env_steps"] == 120
    # Placed as an uninterrupted run's arrays are (uncommitted): so the resumed run's programs are the
    # ones it compiled before, which the compilation cache holds (committed arrays compiled new ones).
    placement = [x.committed for x in jax.tree.leaves(partial_state)]
    assert not any(placement) and [x.committed for x in jax.tree.leaves(state)] == placement
    leaves = jax.tree_util.tree_leaves_with_path(jax.device_get(state))
    full_leaves = jax.tree_util.tree_leaves(full_state)
    assert len(leaves) == len(full_leaves) > 20
    for (path, a), b in zip(leaves, full_leaves):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))
    # The metrics log continues where the checkpoint was, without duplicated rows.
    with (d / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [int(float(r["env_steps"])) for r in rows] == list(range(40, 201, 40))


def _with_total(cfg, total, **sac):
    loop = dataclasses.replace(cfg.train.loop, total_env_steps=total)
    return dataclasses.replace(
        cfg, train=dataclasses.replace(cfg.train, loop=loop, sac=dataclasses.replace(cfg.train.sac, **sac))
    )


def test_a_finished_run_trained_longer_equals_a_run_of_that_length(full_run, tmp_path, toy, capsys):
    """`--resume` with a larger total: the run of 160 env steps, trained on to 200, holds exactly the
    state of the uninterrupted 200-step run (its evaluations fall on the same steps)."""
    cfg, _, _, full_state = full_run
    d = tmp_path / "short"
    short, _ = run_mod.run(_with_total(cfg, 160), d, adapter=toy, checkpoint_every=2)
    assert short["env_steps"] == 160 and (d / "summary.json").is_file()
    summary, state = run_mod.run(cfg, d, adapter=toy, resume=True)
    assert summary["trained_longer_from_env_steps"] == 160 and summary["resumed_from_env_steps"] == 160
    for (path, a), b in zip(
        jax.tree_util.tree_leaves_with_path(jax.device_get(state)), jax.tree_util.tree_leaves(full_state)
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))
    assert json.loads((d / "config.json").read_text())["train"]["loop"]["total_env_steps"] == 200
    assert json.loads((d / "summary.json").read_text())["env_steps"] == 200
    with (d / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [int(float(r["env_steps"])) for r in rows] == list(range(40, 201, 40))
    assert [int(float(r["env_steps"])) for r in rows if r.get("eval/mean_reward")] == [80, 160, 200]
    assert policies.load_policy(d / "final_policy").scores["env_steps"] == 200
    # Shorter, or anything else changed, or a learning rate decayed over the old length: refused.
    with pytest.raises(ValueError, match="different configuration: train.loop.total_env_steps"):
        run_mod.run(_with_total(cfg, 120), d, adapter=toy, resume=True)
    with pytest.raises(ValueError, match=r"different configuration: .*train\.sac\.lr"):
        run_mod.run(_with_total(cfg, 240, lr=3e-4), d, adapter=toy, resume=True)
    decayed = tmp_path / "decayed"
    import shutil

    shutil.copytree(d, decayed)
    rec = json.loads((decayed / "config.json").read_text())
    rec["train"]["sac"]["lr_decay"] = True
    (decayed / "config.json").write_text(json.dumps(rec))
    with pytest.raises(ValueError, match="lr_decay"):
        run_mod.run(_with_total(cfg, 240, lr_decay=True), decayed, adapter=toy, resume=True)
    assert (decayed / "summary.json").is_file()  # refused before anything changed
    garbled = tmp_path / "garbled"
    shutil.copytree(d, garbled)
    for p in (garbled / "checkpoints" / "200" / "state").rglob("*"):
        if p.is_file() and p.stat().st_size > 100:
            p.write_bytes(b"\x00garbage" * 4)
    with pytest.raises(ValueError, match="corrupt"):
        run_mod.run(_with_total(cfg, 240), garbled, adapter=toy, resume=True)
    assert json.loads((garbled / "config.json").read_text())["train"]["loop"]["total_env_steps"] == 200
    assert (garbled / "summary.json").is_file()  # an unreadable checkpoint leaves the run as it was
    # The command line: only --total-env-steps goes with --resume, and only upwards.
    assert cli_main(["train", "--resume", "--run-dir", str(d), "--total-env-steps", "120"]) == 2
    assert "longer, not shorter" in capsys.readouterr().err
    assert cli_main(["train", "--resume", "--run-dir", str(d), "--total-env-steps", "240", "--lr", "0.1"]) == 2
    assert "only --total-env-steps" in capsys.readouterr().err
    assert cli_main(["train", "--resume", "--run-dir", str(d), "--total-env-steps", "200"]) == 0
    assert "has finished" in capsys.readouterr().out


def _rewrite_checkpoint_120(d, cfg, toy, transform, meta_transform=lambda meta: meta) -> None:
    """A run stopped after 3 batches, its checkpoint of 120 env steps written again as `transform` of its
    state (what an older or a damaged release would have left), its record as `meta_transform` of it
    (unchanged by default)."""
    import shutil

    import orbax.checkpoint as ocp

    run_mod.run(cfg, d, adapter=toy, checkpoint_every=1, stop_after=3)
    ckpts = checkpoints.Checkpoints(d / "checkpoints")
    state = latest_state(d, cfg, toy)
    meta = ckpts.manager.restore(120, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]
    shutil.rmtree(d / "checkpoints" / "120")
    ckpts = checkpoints.Checkpoints(d / "checkpoints")
    saved = ocp.args.Composite(
        state=ocp.args.StandardSave(transform(state)), meta=ocp.args.JsonSave(meta_transform(meta))
    )
    ckpts.manager.save(120, args=saved, force=True)
    ckpts.manager.wait_until_finished()


def test_a_checkpoint_written_before_a_state_field_existed_resumes_exactly(full_run, tmp_path, toy):
    """Checkpoints of runs trained before `TrainState.anchor_actor_params` existed (the comparison's
    seed-2 runs) hold every other field: they resume, the new field at its initial value."""

    cfg, _, _, full_state = full_run
    d = tmp_path / "old"
    _rewrite_checkpoint_120(
        d,
        cfg,
        toy,
        lambda state: {
            f.name: getattr(state, f.name) for f in dataclasses.fields(state) if f.name not in checkpoints.ADDED_FIELDS
        },
    )
    with pytest.warns(UserWarning, match="written before TrainState had anchor_actor_params"):
        _, resumed = run_mod.run(cfg, d, adapter=toy, resume=True)
    assert not any(x.committed for x in jax.tree.leaves(resumed))  # placed as a fresh run's (see above)
    for (path, a), b in zip(
        jax.tree_util.tree_leaves_with_path(jax.device_get(resumed)), jax.tree_util.tree_leaves(full_state)
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))


def _with_task_copies(config: dict) -> dict:
    """A config dict as written before the learner's copies of the task's facts were removed."""
    old = json.loads(json.dumps(config))
    old["train"]["loop"]["episode_len"] = old["env"]["episode_length"]
    old["train"]["replay"]["success_tau"] = old["env"]["success_tau"]
    return old


def test_a_run_written_with_the_learners_copies_resumes_exactly(full_run, tmp_path, toy):
    """A run directory of a release whose learner held copies of the task's facts (config.json and the
    checkpoint's record with train.loop.episode_len and train.replay.success_tau) is the same
    configuration: it resumes to the uninterrupted run's state, and its saved policies load."""
    cfg, full_dir, _, full_state = full_run
    d = tmp_path / "copies"
    _rewrite_checkpoint_120(
        d, cfg, toy, lambda state: state, lambda meta: {**meta, "config": _with_task_copies(meta["config"])}
    )
    (d / "config.json").write_text(json.dumps(_with_task_copies(json.loads((d / "config.json").read_text()))))
    assert "episode_len" in json.loads((d / "config.json").read_text())["train"]["loop"]
    assert run_mod._check_same_config(d, cfg) is None
    _, resumed = run_mod.run(cfg, d, adapter=toy, resume=True)
    for (path, a), b in zip(
        jax.tree_util.tree_leaves_with_path(jax.device_get(resumed)), jax.tree_util.tree_leaves(full_state)
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))
    old_policy = tmp_path / "old_policy"
    old_policy.with_suffix(".msgpack").write_bytes((full_dir / "best_policy.msgpack").read_bytes())
    record = json.loads((full_dir / "best_policy.json").read_text())
    old_policy.with_suffix(".json").write_text(json.dumps({**record, "config": _with_task_copies(record["config"])}))
    assert policies.load_policy(old_policy).config == cfg
    # A record whose copy disagrees with its environment describes no one task: refused by name.
    record["config"] = _with_task_copies(record["config"])
    record["config"]["train"]["loop"]["episode_len"] = 7
    old_policy.with_suffix(".json").write_text(json.dumps(record))
    with pytest.raises(
        ValueError, match=r"config\.train\.loop\.episode_len \(7\) differs from config\.env\.episode_length"
    ):
        policies.load_policy(old_policy)


def test_a_checkpoint_whose_added_field_does_not_match_is_refused_not_defaulted(full_run, tmp_path, toy, monkeypatch):
    """The fallback for fields added since is for checkpoints that lack them: one that holds the field
    with other shapes is refused by name, not restored with the field silently taken from the run."""

    cfg, _, _, _ = full_run
    d = tmp_path / "odd"
    _rewrite_checkpoint_120(
        d,
        cfg,
        toy,
        lambda state: state.replace(
            anchor_actor_params=jax.tree.map(lambda x: np.zeros(x.shape + (2,), x.dtype), state.anchor_actor_params)
        ),
    )
    import orbax.checkpoint as ocp

    restored, restore = [], ocp.CheckpointManager.restore

    def spy(self, step, *args, **kwargs):  # which items each restore reads
        restored.append(list(kwargs["args"].keys()))
        return restore(self, step, *args, **kwargs)

    monkeypatch.setattr(ocp.CheckpointManager, "restore", spy)
    # Named with both shapes, and refused from the checkpoint's metadata before any array is read (a
    # restore failing half way left orbax's reads of the other arrays pending).
    with pytest.raises(
        ValueError, match=r"does not match this run's state .*anchor_actor_params/\S+: saved float32\[.*, 2\]"
    ):
        run_mod.run(cfg, d, adapter=toy, resume=True)
    assert restored and all("state" not in items for items in restored)


def test_run_writes_logs_checkpoints_and_policies(full_run):
    cfg, d, summary, state = full_run
    with (d / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 5
    evals = [r for r in rows if r.get("eval/mean_reward")]
    assert [int(float(r["env_steps"])) for r in evals] == [80, 160, 200]
    assert list((d / "tb").glob("events.out.tfevents.*"))
    assert checkpoints.Checkpoints(d / "checkpoints").latest() == 200
    assert json.loads((d / "config.json").read_text())["train"]["loop"]["total_env_steps"] == 200
    best = policies.load_policy(d / "best_policy")
    assert best.config == cfg
    jax.tree.map(np.testing.assert_array_equal, best.actor_params, state.best_actor_params)
    assert best.scores["best_eval_mean_reward"] == pytest.approx(max(float(r["eval/mean_reward"]) for r in evals))
    assert summary["updates"] == int(state.sac.step) > 0


def test_resume_refuses_a_different_configuration(full_run, toy):
    cfg, d, _, _ = full_run
    other = dataclasses.replace(
        cfg, train=dataclasses.replace(cfg.train, sac=dataclasses.replace(cfg.train.sac, lr=3e-4))
    )
    with pytest.raises(ValueError, match=r"different configuration: train\.sac\.lr"):
        run_mod.run(other, d, adapter=toy, resume=True)
    # The checkpoint itself also refuses a state of another shape or configuration.
    with pytest.raises(ValueError, match="different configuration"):
        latest_state(d, other, toy)


def test_existing_run_dir_is_not_overwritten(full_run, toy):
    cfg, d, _, _ = full_run
    with pytest.raises(ValueError, match="already holds a run"):
        run_mod.run(cfg, d, adapter=toy)


def test_resume_without_checkpoint_is_an_error(tmp_path, toy, encoder_file):
    with pytest.raises(ValueError, match="no checkpoint"):
        run_mod.run(toy_run_config(encoder_file), tmp_path / "empty", adapter=toy, resume=True)


def test_corrupt_checkpoint_gives_a_clear_error(full_run, tmp_path, toy):
    cfg, d, _, _ = full_run
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(d, copy)
    step_dir = copy / "checkpoints" / "200"
    files = [p for p in (step_dir / "state").rglob("*") if p.is_file() and p.stat().st_size > 100]
    assert files
    for p in files:
        p.write_bytes(b"\x00garbage" * 4)
    with pytest.raises(ValueError, match="corrupt"):
        latest_state(copy, cfg, toy)


def test_policy_files_are_validated(full_run, tmp_path):
    cfg, d, _, _ = full_run
    with pytest.raises(ValueError, match="not found"):
        policies.load_policy(tmp_path / "nothing")
    bad = tmp_path / "bad"
    (tmp_path / "bad.json").write_text((d / "best_policy.json").read_text())
    (tmp_path / "bad.msgpack").write_bytes((d / "best_policy.msgpack").read_bytes()[:100])
    with pytest.raises(ValueError, match="corrupt"):
        policies.load_policy(bad)
    # Weights of another agent kind under this record: shapes do not match.
    rec = json.loads((d / "best_policy.json").read_text())
    rec["config"]["agent"] = rec["config"]["train"]["agent"]["kind"] = "vpm"
    (tmp_path / "bad.json").write_text(json.dumps(rec))
    (tmp_path / "bad.msgpack").write_bytes((d / "best_policy.msgpack").read_bytes())
    with pytest.raises(ValueError, match="do not match a vpm network"):
        policies.load_policy(bad)
    rec["version"] = 99
    (tmp_path / "bad.json").write_text(json.dumps(rec))
    with pytest.raises(ValueError, match="format version 99"):
        policies.load_policy(bad)


# --- reliability: signals, crashes, concurrent runs -----------------------------------------------------
def test_sigint_stops_after_the_batch_with_a_checkpoint_and_resume_continues(full_run, tmp_path, toy):
    cfg, _, _, full_state = full_run
    d = tmp_path / "interrupted"
    handler = signal.getsignal(signal.SIGINT)

    def ctrl_c(metrics):  # Ctrl-C during the third batch (120 env steps: no evaluation, no scheduled checkpoint)
        if int(metrics["env_steps"]) == 120:
            os.kill(os.getpid(), signal.SIGINT)

    partial, _ = run_mod.run(cfg, d, adapter=toy, stop_on_signal=True, on_iteration=ctrl_c)
    assert (partial["interrupted_at_env_steps"], partial["signal"]) == (120, "SIGINT")
    assert checkpoints.Checkpoints(d / "checkpoints").latest() == 120  # written because of the signal
    assert signal.getsignal(signal.SIGINT) is handler  # the process's own handler is back
    summary, state = run_mod.run(cfg, d, adapter=toy, resume=True)
    assert summary["resumed_from_env_steps"] == 120
    for a, b in zip(jax.tree.leaves(jax.device_get(state)), jax.tree.leaves(full_state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_train_command_stops_on_signals_and_says_how_to_resume(full_run, monkeypatch, capsys):
    cfg, d, _, _ = full_run
    seen = {}

    def interrupted_run(cfg, run_dir, **kwargs):  # what run() returns after a Ctrl-C
        seen.update(kwargs)
        return {"stopped_at_env_steps": 120, "interrupted_at_env_steps": 120, "signal": "SIGINT"}, None

    monkeypatch.setattr(run_mod, "run", interrupted_run)
    monkeypatch.setattr(run_mod, "load_config", lambda path: cfg)
    monkeypatch.setattr(run_mod, "finished_summary", lambda *a: None)
    with pytest.raises(SystemExit) as exit_:
        cli_main(["train", "--resume", "--run-dir", str(d)])
    assert exit_.value.code == 130 and seen["stop_on_signal"] is True
    assert f"mjx-push train --resume --run-dir {d}" in capsys.readouterr().out


def test_a_second_signal_interrupts_at_once():
    from mjx_push.train.runs.signals import StopOnSignal

    before = signal.getsignal(signal.SIGTERM)
    with StopOnSignal() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.01)  # let the interpreter run the handler
        assert stop.requested == "SIGTERM"
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)
    assert signal.getsignal(signal.SIGTERM) is before


def test_kill_9_while_a_checkpoint_is_written_resumes_to_the_same_result(full_run, tmp_path, toy, encoder_file):
    cfg, _, _, full_state = full_run
    d = tmp_path / "killed"
    r = subprocess.run(
        [sys.executable, "-m", "tests.crash_run", str(d), encoder_file],
        cwd=Path(__file__).resolve().parents[1],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == -signal.SIGKILL, r.stdout[-2000:] + r.stderr[-3000:]
    ckpt = d / "checkpoints"
    assert list(ckpt.glob("120.orbax-checkpoint-tmp*"))  # the half-committed checkpoint is still there
    assert checkpoints.Checkpoints(ckpt).latest() == 80  # ... and is not taken for one
    summary, state = run_mod.run(cfg, d, adapter=toy, resume=True)
    assert summary["resumed_from_env_steps"] == 80
    for a, b in zip(jax.tree.leaves(jax.device_get(state)), jax.tree.leaves(full_state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert not list(ckpt.glob("*tmp*"))  # leftovers cleaned up
    with (d / "metrics.csv").open() as f:
        assert [int(float(r["env_steps"])) for r in csv.DictReader(f)] == list(range(40, 201, 40))


def test_two_runs_into_one_directory_are_refused(tmp_path, toy, encoder_file):
    from mjx_push.train.runs.lock import RunLock

    d = tmp_path / "busy"
    d.mkdir()
    with RunLock(d):  # another process's run (flock: a second descriptor conflicts as another process would)
        with pytest.raises(ValueError, match=rf"{d} is in use by another mjx-push process \(pid {os.getpid()}\)"):
            run_mod.run(toy_run_config(encoder_file), d, adapter=toy)
        with pytest.raises(ValueError, match="in use"):
            run_mod.run(toy_run_config(encoder_file), d, adapter=toy, resume=True)
    assert sorted(p.name for p in d.iterdir()) == [".lock"]  # refused before touching anything


def test_resume_of_a_finished_run_says_so_and_changes_nothing(full_run, toy, capsys):
    cfg, d, _, _ = full_run
    before = {p: (p.stat().st_mtime_ns, p.stat().st_size) for p in d.rglob("*")}
    with pytest.raises(run_mod.RunFinished, match="has finished"):
        run_mod.run(cfg, d, adapter=toy, resume=True)
    assert cli_main(["train", "--resume", "--run-dir", str(d)]) == 0
    out = capsys.readouterr().out
    assert "has finished" in out and "Nothing was changed" in out
    assert {p: (p.stat().st_mtime_ns, p.stat().st_size) for p in d.rglob("*")} == before


def test_cli_rejects_bad_settings(capsys):
    assert cli_main(["train", "--lr", "-1", "--run-dir", "/nonexistent/never"]) == 2
    assert "--lr must be" in capsys.readouterr().err
    assert cli_main(["train", "--num-envs", "0", "--run-dir", "/nonexistent/never"]) == 2
    err = capsys.readouterr().err
    assert "--num-envs must be" in err and "loop." not in err
    with pytest.raises(SystemExit):
        cli_main(["train", "--agent", "dqn"])
    assert "dqn" in capsys.readouterr().err
    assert cli_main(["train", "--success-tau", "0", "--run-dir", "/nonexistent/never"]) == 2
    assert "--success-tau must be" in capsys.readouterr().err


def test_cli_shows_a_bug_with_its_traceback_and_bad_input_as_one_line(monkeypatch, capsys):
    """Only ConfigError (the user's input) becomes exit status 2; any other error, a ValueError from a
    bug included, propagates so its traceback shows."""
    from mjx_push.errors import ConfigError
    from mjx_push.cli import Demo

    def bug(self):
        raise ValueError("operands could not be broadcast together")  # what a shape bug raises

    monkeypatch.setattr(Demo, "run", bug)
    with pytest.raises(ValueError, match="broadcast"):
        cli_main(["demo"])

    def bad_input(self):
        raise ConfigError("--num-envs must be >= 1, got 0")

    monkeypatch.setattr(Demo, "run", bad_input)
    assert cli_main(["demo"]) == 2
    assert capsys.readouterr().err.strip() == "mjx-push: error: --num-envs must be >= 1, got 0"


def test_success_tau_sets_the_environment_and_the_relabelling_radius():
    from mjx_push.cli import Train

    cfg = Train(agent="vpm", preset="reference", success_tau=0.05).config()
    assert cfg.env.success_tau == 0.05  # the task's radius, which the learner reads from its environment
    assert not hasattr(cfg.train.replay, "success_tau")  # no copy of it
    assert Train(agent="vpm", preset="reference").config().env.success_tau == 0.01


def test_set_on_a_removed_copy_of_the_task_names_the_environments_field(capsys):
    """`--set` on the learner's former copies of the task's facts says which field to set instead."""
    for bad, says in (
        (
            "train.replay.success_tau=0.05",
            "--set train.replay.success_tau: the learner reads the task's value from "
            "the environment; set env.success_tau instead",
        ),
        (
            "train.loop.episode_len=30",
            "--set train.loop.episode_len: the learner reads the task's value from the "
            "environment; set env.episode_length instead",
        ),
    ):
        assert cli_main(["train", "--set", bad, "--run-dir", "/nonexistent/never"]) == 2
        assert says in capsys.readouterr().err, bad


def test_set_overrides_any_field_by_its_config_path(capsys):
    from mjx_push.cli import Train

    cfg = Train(
        agent="vpm",
        preset="cpu",
        set=(
            "train.sac.bc_weight=0",
            "env.substeps=[10,600]",
            "env.controller.gain=1.0",
            'train.agent.critic_obs="actor"',
        ),
    ).config()
    assert cfg.train.sac.bc_weight == 0 and cfg.env.substeps == (10, 600) and cfg.env.controller.gain == 1.0
    assert cfg.train.agent.critic_obs == "actor" and cfg.train.agent.obs_norm  # the rest stays the preset's
    assert type(cfg.train.sac.bc_weight) is float  # a whole number for a float field is stored as one
    for bad, says in (
        ("train.sac.bcweight=0", "no field 'bcweight'"),
        ("trian.sac.lr=1", "no section 'trian'"),
        ("train.sac.bc_weight=-1", "bc_weight must be"),
        ("train.sac.bc_weight", "PATH=VALUE"),
        ("train.sac.lr=abc", "train.sac.lr must be a number, got 'abc'"),  # a value of the wrong kind
        ("train.loop.num_envs=3.5", "num_envs must be an integer"),
        ("expert.hold_short=1", "hold_short must be true or false"),
    ):
        assert cli_main(["train", "--set", bad, "--run-dir", "/nonexistent/never"]) == 2
        assert says in capsys.readouterr().err, bad


def test_progress_lines_report_success_reward_and_final_distance():
    import io

    from rich.console import Console

    from mjx_push.train.config import LoopConfig
    from mjx_push.cli.progress import TrainProgress

    out = io.StringIO()
    m = {
        "env_steps": 500,
        "env_steps_per_s": 10.0,
        "updates_per_s": 0.0,
        "train/success_rate": 0.1,
        "train/mean_reward": -45.0,
        "train/final_distance": 0.0875,
        "eval/success_rate": 0.25,
        "eval/mean_reward": -40.0,
        "eval/final_distance": 0.123,
    }
    with TrainProgress(Console(file=out, width=200), LoopConfig(), 50, enabled=False) as bar:
        bar.update(m)
    line = out.getvalue()
    assert "500 env steps: train success 10% reward -45.0 final dist 8.8 cm" in line
    assert "eval success 25% reward -40.0 final dist 12.3 cm" in line


def _forked_config(cfg, total=280, seed=5, **demo):
    """`cfg` trained on to `total` with the teacher annealed away over 200-240 env steps, anchored."""
    loop = dataclasses.replace(cfg.train.loop, total_env_steps=total, seed=seed)
    sac = dataclasses.replace(cfg.train.sac, anchor_weight=1.0)
    demo = dataclasses.replace(cfg.train.demo, **({"anneal_start": 200, "anneal_end": 240} | demo))
    return dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, loop=loop, sac=sac, demo=demo))


def _tree_snapshot(d: Path) -> dict:
    return {p: (p.stat().st_mtime_ns, p.stat().st_size) for p in d.rglob("*") if p.name != ".lock"}


def test_a_fork_starts_from_the_checkpoint_with_new_settings_and_resumes_exactly(full_run, tmp_path, toy):
    """`fork`: the source's state at the checkpoint, its own best actor, anchor and random numbers,
    env steps counted on, the source untouched; an interrupted fork resumes to the uninterrupted one."""
    from mjx_push.train.runs.fork import ForkSource

    cfg, d, _, _ = full_run
    fcfg = _forked_config(cfg)
    before = _tree_snapshot(d)
    source = jax.device_get(latest_state(d, cfg, toy, step=160))
    f = tmp_path / "fork"
    partial, _ = run_mod.run(fcfg, f, adapter=toy, fork=ForkSource(d, 160), stop_after=1)
    assert partial["stopped_at_env_steps"] == 200
    start = jax.device_get(latest_state(f, fcfg, toy, step=160))
    for part in ("sac", "buffer", "norm_stats", "env_steps"):
        for (path, a), b in zip(
            jax.tree_util.tree_leaves_with_path(getattr(start, part)), jax.tree.leaves(getattr(source, part))
        ):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=part + jax.tree_util.keystr(path))
    assert int(start.best_env_steps) == -1 and float(start.best_eval_reward) == -np.inf
    jax.tree.map(np.testing.assert_array_equal, start.anchor_actor_params, source.sac.actor_params)
    jax.tree.map(np.testing.assert_array_equal, start.best_actor_params, source.sac.actor_params)
    assert not np.array_equal(np.asarray(start.key), np.asarray(source.key))

    summary, state = run_mod.run(fcfg, f, adapter=toy, resume=True)
    assert summary["env_steps"] == 280 and summary["forked_from"]["env_steps"] == 160
    record = json.loads((f / "forked_from.json").read_text())
    assert record["run_dir"] == str(d.absolute()) and record["env_steps"] == 160
    assert any(c.startswith("train.demo.anneal_start:") for c in record["changes"])
    with (f / "metrics.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [int(float(r["env_steps"])) for r in rows] == [200, 240, 280]
    assert [float(r["demo/teacher_scale"]) for r in rows] == [1.0, 0.0, 0.0]
    assert int(state.best_env_steps) in (240, 280)  # only the fork's own evaluations count
    assert _tree_snapshot(d) == before  # the source is only read

    whole, whole_state = run_mod.run(fcfg, tmp_path / "whole", adapter=toy, fork=ForkSource(d, 160))
    assert not any(x.committed for x in jax.tree.leaves(whole_state))  # the source's arrays placed as a fresh run's
    for (path, a), b in zip(
        jax.tree_util.tree_leaves_with_path(jax.device_get(state)), jax.tree.leaves(jax.device_get(whole_state))
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))


def test_a_fork_that_cannot_start_is_refused_before_anything_is_written(full_run, tmp_path, toy):
    from mjx_push.train.runs.fork import ForkSource

    cfg, d, _, _ = full_run
    f = tmp_path / "fork"
    bigger = dataclasses.replace(
        cfg, train=dataclasses.replace(cfg.train, agent=dataclasses.replace(cfg.train.agent, hidden=(64, 64)))
    )
    cases = [
        (_forked_config(bigger), ForkSource(d), r"keeps its source's networks.*train\.agent\.hidden"),
        (_forked_config(cfg, total=200, anneal_start=160, anneal_end=200), ForkSource(d), "must exceed"),
        (_forked_config(cfg), ForkSource(d, 120), r"no checkpoint at 120 env steps \(it has: 160, 200\)"),
        (_forked_config(cfg), ForkSource(tmp_path / "nothing"), "not a run directory"),
    ]
    for fcfg, source, message in cases:
        with pytest.raises(ValueError, match=message):
            run_mod.run(fcfg, f, adapter=toy, fork=source)
        assert not f.exists()
    with pytest.raises(ValueError, match="pass one of them"):
        run_mod.run(_forked_config(cfg), d, adapter=toy, fork=ForkSource(d), resume=True)


def test_train_command_forks_a_run_with_the_options_given(full_run, tmp_path, monkeypatch, capsys):
    cfg, d, _, _ = full_run
    seen = {}

    def forked_run(cfg, run_dir, **kwargs):
        seen.update(cfg=cfg, run_dir=run_dir, **kwargs)
        step, changes = check_fork(kwargs["fork"], cfg)  # as the run does before it calls on_start
        kwargs["on_start"](run_mod.Start(step, tuple(changes)))
        return {"best_eval_mean_reward": -1.0, "best_eval_success_rate": 1.0, "best_env_steps": 240}, None

    monkeypatch.setattr(run_mod, "run", forked_run)
    args = ["train", "--fork-from", str(d), "--fork-step", "160", "--total-env-steps", "280", "--seed", "3"]
    set_ = ["--set", "train.demo.anneal_start=200", "train.demo.anneal_end=240", "train.sac.anchor_weight=1"]
    assert cli_main([*args, *set_]) == 0
    out = capsys.readouterr().out
    assert seen["fork"].run_dir == d and seen["fork"].env_steps == 160 and seen["run_dir"] == Path(f"{d}-fork")
    assert seen["cfg"] == _forked_config(cfg, seed=3)  # the source's configuration, changed by the options
    assert "forked from" in out and "train.demo.anneal_start: None != 200" in out
    # Bad combinations: a clear message each (from the command or from the run's own checks), nothing run.
    monkeypatch.undo()
    bad = [
        (["train", "--fork-step", "160"], "pass --fork-from too"),
        (["train", "--fork-from", str(d), "--resume", "--run-dir", str(tmp_path)], "pass one of them"),
        (["train", "--fork-from", str(d), "--agent", "egru", "--total-env-steps", "280"], "keeps its source's agent"),
        (["train", "--fork-from", str(d), "--run-dir", str(tmp_path / "f")], "must exceed"),
    ]
    for argv, message in bad:
        assert cli_main(argv) == 2, argv
        assert message in capsys.readouterr().err
    assert not (tmp_path / "f").exists() and not list(tmp_path.iterdir())

"""Training runs on disk (train/run.py) on the toy task: exact resume from orbax checkpoints, clear
errors for corrupt or mismatched checkpoints and policies, logs and saved policies."""

import train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import csv
import dataclasses
import json

import jax
import numpy as np
import pytest

from mjx_push.env import EnvConfig
from train import run as run_mod
from train.cli import main as cli_main
from train.config import AgentConfig, DemoConfig, LoopConfig, ReplayConfig, SACConfig, TrainConfig
from train.presets import RunConfig
from train.toy import make_toy

TAU = 0.025


def toy_run_config(encoder, kind="ugru", seed=0) -> RunConfig:
    # The measured presets' learner (normalisation, privileged critic, demonstrations with behaviour
    # cloning), so checkpoints and saved policies carry everything they add to the state.
    train_cfg = TrainConfig(
        agent=AgentConfig(kind, hidden=(32, 32), gru_hidden=8, critic_hidden=(32, 32), obs_norm=True,
                          critic_obs="privileged", critic_layer_norm=True),
        sac=SACConfig(batch_size=16, bc_weight=1.0, bc_batch_size=8, target_clip=True),
        demo=DemoConfig(warmup=True, fraction=0.25, noise=0.1),
        replay=ReplayConfig(capacity_transitions=2_000, success_tau=TAU),
        loop=LoopConfig(num_envs=4, episode_len=10, total_env_steps=200, warmup_env_steps=80, utd=0.25,
                        eval_every_env_steps=80, eval_episodes=6, seed=seed),
    )
    return RunConfig(agent=kind, preset="smoke", train=train_cfg, env=EnvConfig(episode_length=10, success_tau=TAU),
                     encoder=encoder)


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
    partial, _ = run_mod.run(cfg, d, adapter=toy, checkpoint_every=1, stop_after=3)
    assert partial["stopped_at_env_steps"] == 120
    # Reopen from disk, as a new process would: only the checkpoint carries the state over.
    summary, state = run_mod.run(cfg, d, adapter=toy, resume=True)
    assert summary["resumed_from_env_steps"] == 120
    leaves = jax.tree_util.tree_leaves_with_path(jax.device_get(state))
    full_leaves = jax.tree_util.tree_leaves(full_state)
    assert len(leaves) == len(full_leaves) > 20
    for (path, a), b in zip(leaves, full_leaves):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))
    # The metrics log continues where the checkpoint was, without duplicated rows.
    with (d / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [int(float(r["env_steps"])) for r in rows] == list(range(40, 201, 40))


def test_run_writes_logs_checkpoints_and_policies(full_run):
    cfg, d, summary, state = full_run
    with (d / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 5
    evals = [r for r in rows if r.get("eval/mean_reward")]
    assert [int(float(r["env_steps"])) for r in evals] == [80, 160, 200]
    assert list((d / "tb").glob("events.out.tfevents.*"))
    assert run_mod.Checkpoints(d / "checkpoints").latest() == 200
    assert json.loads((d / "config.json").read_text())["train"]["loop"]["total_env_steps"] == 200
    best = run_mod.load_policy(d / "best_policy")
    assert best.config == cfg
    jax.tree.map(np.testing.assert_array_equal, best.actor_params, state.best_actor_params)
    assert best.scores["best_eval_mean_reward"] == pytest.approx(max(float(r["eval/mean_reward"]) for r in evals))
    assert summary["updates"] == int(state.sac.step) > 0


def test_resume_refuses_a_different_configuration(full_run, toy):
    cfg, d, _, _ = full_run
    other = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, sac=dataclasses.replace(cfg.train.sac, lr=3e-4)))
    with pytest.raises(ValueError, match=r"different configuration: train\.sac\.lr"):
        run_mod.run(other, d, adapter=toy, resume=True)
    # The checkpoint itself also refuses a state of another shape or configuration.
    with pytest.raises(ValueError, match="different configuration"):
        run_mod.latest_state(d, other, toy)


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
        run_mod.latest_state(copy, cfg, toy)


def test_policy_files_are_validated(full_run, tmp_path):
    cfg, d, _, _ = full_run
    with pytest.raises(ValueError, match="not found"):
        run_mod.load_policy(tmp_path / "nothing")
    bad = tmp_path / "bad"
    (tmp_path / "bad.json").write_text((d / "best_policy.json").read_text())
    (tmp_path / "bad.msgpack").write_bytes((d / "best_policy.msgpack").read_bytes()[:100])
    with pytest.raises(ValueError, match="corrupt"):
        run_mod.load_policy(bad)
    # Weights of another agent kind under this record: shapes do not match.
    rec = json.loads((d / "best_policy.json").read_text())
    rec["config"]["agent"] = rec["config"]["train"]["agent"]["kind"] = "vpm"
    (tmp_path / "bad.json").write_text(json.dumps(rec))
    (tmp_path / "bad.msgpack").write_bytes((d / "best_policy.msgpack").read_bytes())
    with pytest.raises(ValueError, match="do not match a vpm network"):
        run_mod.load_policy(bad)
    rec["version"] = 99
    (tmp_path / "bad.json").write_text(json.dumps(rec))
    with pytest.raises(ValueError, match="format version 99"):
        run_mod.load_policy(bad)


def test_cli_rejects_bad_settings(capsys):
    assert cli_main(["train", "--lr", "-1", "--run-dir", "/nonexistent/never"]) == 2
    assert "sac.lr" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["train", "--agent", "dqn"])
    assert "dqn" in capsys.readouterr().err
    assert cli_main(["train", "--success-tau", "0", "--run-dir", "/nonexistent/never"]) == 2
    assert "success_tau" in capsys.readouterr().err


def test_success_tau_sets_the_environment_and_the_relabelling_radius():
    from train.cli import Train

    cfg = Train(agent="vpm", preset="reference", success_tau=0.05).config()
    assert cfg.env.success_tau == cfg.train.replay.success_tau == 0.05
    assert Train(agent="vpm", preset="reference").config().env.success_tau == 0.01


def test_progress_lines_report_success_reward_and_final_distance():
    import io

    from rich.console import Console

    from train.config import LoopConfig
    from train.progress import TrainProgress

    out = io.StringIO()
    m = {"env_steps": 500, "env_steps_per_s": 10.0, "updates_per_s": 0.0, "train/success_rate": 0.1,
         "train/mean_reward": -45.0, "train/final_distance": 0.0875, "eval/success_rate": 0.25,
         "eval/mean_reward": -40.0, "eval/final_distance": 0.123}
    with TrainProgress(Console(file=out, width=200), LoopConfig(), enabled=False) as bar:
        bar.update(m)
    line = out.getvalue()
    assert "500 env steps: train success 10% reward -45.0 final dist 8.8 cm" in line
    assert "eval success 25% reward -40.0 final dist 12.3 cm" in line

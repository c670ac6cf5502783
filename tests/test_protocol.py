"""`mjx-push protocol`: every run of a pre-registered protocol recorded in its data folder as it ends.

Training and evaluation stand in as copies here (the real ones are tested in test_run.py and
test_eval.py, and the protocol's runs use them end to end): these tests check what the protocol adds,
the records, the declared actor and test episodes, failures reported, nothing redone, the refusals."""

import json

import numpy as np
import pytest

from mjx_push.train.comparison import tables as ct
from mjx_push.train.comparison import protocol as proto
from mjx_push.cli import main as cli_main

SHAPES = ["cylinder", "square"]


def _folder(tmp_path, **over):
    folder = tmp_path / "data"
    folder.mkdir(parents=True)
    protocol = {
        "version": "v0",
        "preset": "smoke",
        "agents": ["vpm", "egru"],
        "seeds": [0, 1],
        "shapes": SHAPES,
        "test_seed": 4242,
        "episodes_per_shape": 4,
        "setting": "difficult",
        "actor": "final_policy",
        "env_steps": 800,  # the smoke preset's
        "bootstrap": {"reps": 200, "confidence": 0.95, "seed": 0},
        **over,
    }
    (folder / "protocol.json").write_text(json.dumps(protocol))
    return folder


def _per_episode(success):
    n = len(success)
    return {
        "success": np.asarray(success, float),
        "reward": -np.arange(n, dtype=float),
        "overshoot": np.zeros(n),
        "distance": np.ones(n),
        "final_distance": np.full(n, 0.004),
    }


@pytest.fixture
def stand_ins(monkeypatch):
    """Training writes what a finished run leaves; evaluation the cache a real one writes, recording the
    policy and spec it was asked for."""
    from mjx_push.train.evaluate import summarize

    calls = {"train": [], "eval": [], "fail": set()}

    def train_or_reuse(cfg, run_dir, log, fork=None):
        calls["train"].append((cfg.agent, cfg.train.loop.seed, run_dir))
        if (cfg.agent, cfg.train.loop.seed) in calls["fail"]:
            raise RuntimeError("the simulator blew up")
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "summary.json").write_text(json.dumps({"env_steps": cfg.train.loop.total_env_steps, "wall_s": 1.0}))

    def evaluate_run(cfg, run_dir, spec, log, policy=None):
        calls["eval"].append((cfg.agent, policy, spec.seed, spec.setting, spec.shape, spec.episodes))
        per = _per_episode([1, 1, 0, cfg.train.loop.seed % 2])
        record = {"summary": summarize(per), "per_episode": {k: v.tolist() for k, v in per.items()}}
        (run_dir / f"eval-{spec.setting}-{spec.shape}-{spec.episodes}.json").write_text(json.dumps(record))

    def evaluate(policy, spec):
        per = _per_episode([1, 1, 1, 1])
        return {"summary": summarize(per), "per_episode": per}

    monkeypatch.setattr(proto, "train_or_reuse", train_or_reuse)
    monkeypatch.setattr(proto, "evaluate_run", evaluate_run)
    monkeypatch.setattr(proto, "evaluate", evaluate)
    monkeypatch.setattr(proto, "source_commit", lambda: "abc1234")
    return calls


def test_every_run_is_recorded_with_the_declared_actor_and_test_episodes(tmp_path, stand_ins):
    folder = _folder(tmp_path)
    runs = proto.ProtocolRuns(folder, tmp_path / "out", log=lambda _: None)
    proto.run_all(runs)
    assert sorted(a for a, *_ in stand_ins["train"]) == ["egru", "egru", "vpm", "vpm"]
    assert {(policy, seed, setting, episodes) for _, policy, seed, setting, _, episodes in stand_ins["eval"]} == {
        ("final_policy", 4242, "difficult", 4)
    }
    record = json.loads((folder / "runs" / "egru-s1.json").read_text())
    assert record["status"] == "finished" and record["commit"] == "abc1234" and record["env_steps"] == 800
    assert record["shapes"]["square"]["per_episode"]["success"] == [1.0, 1.0, 0.0, 1.0]
    results = ct.load(folder)  # the tables read exactly what the jobs wrote
    assert [r.status for r in results.runs] == ["finished"] * 4
    np.testing.assert_allclose(results.table("egru", "success"), [[0.5, 0.5], [0.75, 0.75]])
    assert results.expert_row("success").tolist() == [1.0, 1.0]
    # A second call redoes nothing.
    stand_ins["train"].clear()
    proto.run_all(runs)
    assert stand_ins["train"] == []


def test_a_failed_run_is_recorded_as_failed_then_finished_when_it_succeeds(tmp_path, stand_ins):
    folder = _folder(tmp_path)
    runs = proto.ProtocolRuns(folder, tmp_path / "out", log=lambda _: None)
    stand_ins["fail"].add(("vpm", 1))
    with pytest.raises(RuntimeError, match="blew up"):
        proto.run_job(runs, "vpm", 1)
    record = json.loads((folder / "runs" / "vpm-s1.json").read_text())
    assert record["status"] == "failed" and "the simulator blew up" in record["note"]
    proto.expert_job(runs)
    table = ct.runs_table(ct.load(folder))
    assert any("failed" in line and "VPM" in line and "| 1 |" in line for line in table.splitlines()), table
    stand_ins["fail"].clear()
    assert proto.run_job(runs, "vpm", 1)["status"] == "finished"


def test_plan_lists_every_run_seed_major_then_the_expert_and_the_tables(tmp_path):
    folder = _folder(tmp_path)
    lines = proto.plan(proto.ProtocolRuns(folder, tmp_path / "out"))
    base = f"mjx-push protocol {folder} --out {tmp_path / 'out'}"
    assert lines == [
        f"{base} --job vpm:0",
        f"{base} --job egru:0",
        f"{base} --job vpm:1",
        f"{base} --job egru:1",
        f"{base} --job expert",
        f"python -m mjx_push.train.comparison.tables {folder} --write",
    ]


def test_a_protocols_set_items_reach_every_run_and_a_bad_one_is_refused_before_any_work(tmp_path, capsys, stand_ins):
    folder = _folder(tmp_path, set=["env.perturb.latency=30", "env.perturb.sample=uniform"])
    runs = proto.ProtocolRuns(folder, tmp_path / "out", log=lambda _: None)
    cfg = runs.config("egru", 1)
    assert (cfg.env.perturb.latency, cfg.env.perturb.sample) == (30, "uniform")
    assert cfg.train.loop.seed == 1 and ct.load_protocol(folder).sets == tuple(
        json.loads((folder / "protocol.json").read_text())["set"]
    )
    assert ct.load_protocol(_folder(tmp_path / "plain")).sets == ()  # protocol v1 has none: the preset alone
    caption = ct._episodes_caption(ct.load_protocol(folder))
    assert caption.endswith("800 env steps; trained with --set env.perturb.latency=30 env.perturb.sample=uniform)")
    bad = _folder(tmp_path / "bad", set=["env.perturb.latencyy=30"])
    assert cli_main(["protocol", str(bad), "--out", str(tmp_path / "out2")]) == 2
    err = capsys.readouterr().err
    assert "protocol.json: field 'set'" in err and "env.perturb.latencyy" in err
    assert not (bad / "runs").exists() and stand_ins["train"] == []


def test_a_protocol_the_preset_does_not_match_is_refused_before_any_work(tmp_path, capsys, stand_ins):
    folder = _folder(tmp_path, env_steps=1600)
    assert cli_main(["protocol", str(folder), "--out", str(tmp_path / "out")]) == 2
    assert "declares 1,600" in capsys.readouterr().err
    assert not (folder / "runs").exists() and stand_ins["train"] == []
    folder2 = _folder(tmp_path / "b")
    assert cli_main(["protocol", str(folder2), "--job", "ppo:0"]) == 2
    assert "AGENT:SEED of protocol v0" in capsys.readouterr().err
    assert cli_main(["protocol", str(tmp_path / "nowhere")]) == 2
    assert "protocol.json" in capsys.readouterr().err

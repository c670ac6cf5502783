"""benchmarks.robust_study: study robust-v1's decision follows its pre-registered rule, its report names
every run, and records of the wrong episodes are refused."""

import json

import pytest

from benchmarks import robust_study as rs

TEST_SEED = 7001009


def _study(tmp_path):
    study = tmp_path / "robust-v1"
    for arm in rs.ARMS:
        (study / arm).mkdir(parents=True)
        (study / arm / "protocol.json").write_text(json.dumps({"seeds": [0, 1], "test_seed": TEST_SEED}))
    return study


def _record(clean, rows, seed=rs.SELECTION_SEED, levels=("realistic",)):
    """A stress record with the fields the study reads: per-row success at the realistic level (mean
    over shapes), the clean row and the noise floor, and its score."""

    def row(name, level, success):
        return {"perturbation": name, "level": level, "mean": {"success": success}, "skipped": None, "per_episode": [1]}

    return {
        "config": {"seed": seed, "levels": list(levels)},
        "rows": [row("clean", None, clean), row("noise_floor", None, clean - 0.01)]
        + [row(name, "realistic", s) for name, s in rows.items()],
        "score": {"clean": clean, "realistic": sum(rows.values()) / len(rows)},
        "wall_s": 60.0,
    }


def _add(study, tmp_path, arm, seed, record, replace=False):
    """Keep `record` as run (arm, seed)'s; `replace`: remove the study's record of those episodes first
    (a record is never replaced by `add`)."""
    path = tmp_path / f"{arm}-{seed}-{record['config']['seed']}.json"
    path.write_text(json.dumps(record))
    if replace:
        kind = "select" if record["config"]["seed"] == rs.SELECTION_SEED else "test"
        (study / "stress" / f"{arm}-s{seed}-{kind}.json").unlink()
    return rs.add(path, arm, seed, study)


def _plain_arm_stressed(tmp_path):
    """A study whose plain arm has both selection records: 95 % clean, score 85 %."""
    study = _study(tmp_path)
    for seed in (0, 1):
        _add(study, tmp_path, "plain", seed, _record(0.95, {"latency": 0.80, "mass": 0.90}))
    return study


def test_without_records_every_run_is_named_pending(tmp_path):
    text = rs.block(_study(tmp_path))
    assert text.count("not yet stressed") == 4
    assert "Decision pending: no selection record yet for plain s0, plain s1, randomised s0, randomised s1." in text
    assert "Not yet stressed on the test episodes: plain s0, plain s1, randomised s0, randomised s1." in text


def test_the_rule_ships_a_better_score_at_equal_clean_and_not_a_lower_clean(tmp_path):
    study = _plain_arm_stressed(tmp_path)
    _add(study, tmp_path, "randomised", 0, _record(0.94, {"latency": 0.90, "mass": 0.92}))
    text = rs.block(study)
    assert "Decision pending: no selection record yet for randomised s1." in text and "Whatever" not in text
    _add(study, tmp_path, "randomised", 1, _record(0.94, {"latency": 0.90, "mass": 0.92}))
    text = rs.block(study)
    assert "| **plain, mean** | 95.0 | 85.0 |" in text and "| **randomised, mean** | 94.0 | 91.0 |" in text
    assert (
        "Decision: the randomised eGRU ships as `pretrained:egru-robust`, actor randomised-s0 (robustness score 91.0 against 85.0"
        in text
    )
    # 3 points of clean success lost: more than the rule allows, whatever the score
    with pytest.raises(rs.StudyError, match="randomised-s1-select.json exists with another record"):
        _add(study, tmp_path, "randomised", 1, _record(0.90, {"latency": 0.90, "mass": 0.92}))
    assert "| randomised s1 | 94.0 | 91.0 |" in rs.block(study)  # the kept record is unchanged
    _add(study, tmp_path, "randomised", 1, _record(0.90, {"latency": 0.90, "mass": 0.92}), replace=True)
    text = rs.block(study)
    assert "the randomised eGRU does not ship" in text and "clean success 92.0 against 95.0: more than 2 points" in text
    # a score not above the plain arm's does not ship either
    for seed in (0, 1):
        _add(study, tmp_path, "randomised", seed, _record(0.95, {"latency": 0.80, "mass": 0.90}), replace=True)
    assert "does not ship (robustness score 85.0 against 85.0: not above" in rs.block(study)


def test_the_report_shows_every_test_record_and_reads_the_target_on_randomised_seed_0(tmp_path):
    study = _study(tmp_path)
    _add(study, tmp_path, "plain", 0, _record(0.96, {"latency": 0.80, "mass": 0.90}, seed=TEST_SEED))
    _add(study, tmp_path, "randomised", 0, _record(0.95, {"latency": 0.93, "mass": 0.91}, seed=TEST_SEED))
    text = rs.block(study)
    assert "| plain-s0 | 96 |" in text and "| randomised-s0 | 95 |" in text
    assert "Not yet stressed on the test episodes: plain s1, randomised s1." in text
    assert "Target (randomised s0, test episodes): met: its largest loss from clean is 4.0 points (mass" in text
    _add(study, tmp_path, "randomised", 0, _record(0.95, {"latency": 0.85, "mass": 0.91}, seed=TEST_SEED), replace=True)
    assert "not met: its largest loss from clean is 10.0 points (latency" in rs.block(study)


def test_records_of_other_episodes_or_runs_are_refused_naming_the_field(tmp_path):
    study = _study(tmp_path)
    with pytest.raises(rs.StudyError, match="field 'config.seed' is 12345: neither the selection seed"):
        _add(study, tmp_path, "plain", 0, _record(0.9, {"mass": 0.9}, seed=12345))
    with pytest.raises(rs.StudyError, match="no 'realistic' level"):
        _add(study, tmp_path, "plain", 0, _record(0.9, {"mass": 0.9}, levels=("mild",)))
    with pytest.raises(rs.StudyError, match="plain s7 is not a run of study robust-v1"):
        _add(study, tmp_path, "plain", 7, _record(0.9, {"mass": 0.9}))
    assert not (study / "stress").exists()
    kept = _add(study, tmp_path, "plain", 0, _record(0.9, {"mass": 0.9}))
    assert kept.name == "plain-s0-select.json" and "per_episode" not in kept.read_text()
    # a record moved under another episodes' name is caught when read
    kept.rename(kept.with_name("plain-s0-test.json"))
    with pytest.raises(rs.StudyError, match="its episodes are not the file name's"):
        rs.load(study)


def test_check_passes_after_write_and_fails_on_a_changed_number(tmp_path, monkeypatch):
    study = _study(tmp_path)
    page = tmp_path / "page.md"
    page.write_text(f"intro\n\n{rs.BEGIN}\nold\n{rs.END}\n\nafter\n")
    monkeypatch.setattr(rs, "STUDY", study)
    monkeypatch.setattr(rs, "PAGE", page)
    assert rs.main(["--check"]) == 1
    assert rs.main(["--write"]) == 0
    assert rs.main(["--check"]) == 0
    text = page.read_text()
    assert text.startswith("intro\n\n") and text.endswith("\n\nafter\n")
    page.write_text(text.replace("plain s0 | not yet stressed", "plain s0 | 95.0"))
    assert rs.main(["--check"]) == 1


def test_the_committed_page_is_what_the_committed_records_print():
    assert rs.main(["--check"]) == 0


def test_every_run_is_listed_with_its_training_record_or_as_having_none(tmp_path):
    study = _study(tmp_path)
    for arm in rs.ARMS:
        proto = json.loads((study / arm / "protocol.json").read_text())
        (study / arm / "protocol.json").write_text(json.dumps({**proto, "shapes": ["cylinder", "square"]}))
    (study / "plain" / "runs").mkdir()
    summary = lambda x: {"summary": {"success": {"mean": x, "sem": 0.0, "n": 100}}}  # noqa: E731
    (study / "plain" / "runs" / "egru-s0.json").write_text(
        json.dumps(
            {
                "status": "finished",
                "env_steps": 128000,
                "note": "resumed at 48,000 env steps",
                "shapes": {"cylinder": summary(1.0), "square": summary(0.95)},
            }
        )
    )
    (study / "plain" / "runs" / "egru-s1.json").write_text(
        json.dumps({"status": "training", "env_steps": 16000, "note": "training in runs/x"})
    )
    text = rs.block(study)
    assert "| run | status | env steps | clean cylinder (%) | clean square (%) | clean mean (%) | note |" in text
    assert "| plain s0 | finished | 128,000 | 100.0 | 95.0 | 97.5 | resumed at 48,000 env steps |" in text
    assert "| plain s1 | training | 16,000 | - | - | - | training in runs/x |" in text
    assert "| randomised s0 | no record yet | - | - | - | - | - |" in text
    (study / "randomised" / "expert.json").write_text(
        json.dumps({"shapes": {"cylinder": summary(1.0), "square": summary(0.9)}})
    )
    assert "| expert (randomised's protocol) | scored | - | 100.0 | 90.0 | 95.0 | reference |" in rs.block(study)
    (study / "plain" / "runs" / "egru-s0.json").write_text(json.dumps({"status": "finished"}))
    with pytest.raises(rs.StudyError, match="egru-s0.json: not a readable run record"):
        rs.block(study)
    (study / "plain" / "runs" / "egru-s0.json").unlink()
    (study / "randomised" / "expert.json").write_text(json.dumps({"shapes": {}}))
    with pytest.raises(rs.StudyError, match="expert.json: not a readable expert record"):
        rs.block(study)


def _rerun(study, arm, seed, label="machine2", success=0.9):
    summary = {"summary": {"success": {"mean": success, "sem": 0.0, "n": 100}}}
    path = study / arm / "reruns" / f"egru-s{seed}-{label}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"status": "finished", "env_steps": 128000, "note": "trained again", "shapes": {"cylinder": summary}}
    path.write_text(json.dumps(record))


def test_a_lost_actor_is_stood_for_by_its_reruns_records_and_its_own_records_win(tmp_path):
    study = _study(tmp_path)
    for arm in rs.ARMS:
        proto = json.loads((study / arm / "protocol.json").read_text())
        (study / arm / "protocol.json").write_text(json.dumps({**proto, "shapes": ["cylinder"]}))
    record = _record(0.9, {"mass": 0.9})
    path = tmp_path / "r.json"
    path.write_text(json.dumps(record))
    with pytest.raises(rs.StudyError, match="--rerun 'machine2': no rerun record .*egru-s0-machine2.json"):
        rs.add(path, "randomised", 0, study, rerun="machine2")
    _rerun(study, "randomised", 0)
    _rerun(study, "plain", 0, success=0.8)
    _add(study, tmp_path, "plain", 0, _record(0.95, {"latency": 0.80, "mass": 0.90}))
    _add(study, tmp_path, "plain", 1, _record(0.95, {"latency": 0.80, "mass": 0.90}))
    _add(study, tmp_path, "randomised", 1, _record(0.94, {"latency": 0.90, "mass": 0.92}))
    assert "no selection record yet for randomised s0." in rs.block(study)
    # a record of another actor than the one named is refused
    path.write_text(json.dumps({**_record(0.94, {"latency": 0.90, "mass": 0.92}), "source": "p/randomised-s0.npz"}))
    with pytest.raises(rs.StudyError, match="the actor policies/randomised-s0.npz, not randomised-s0-machine2.npz"):
        rs.add(path, "randomised", 0, study, rerun="machine2")
    path.write_text(
        json.dumps({**_record(0.94, {"latency": 0.90, "mass": 0.92}), "source": "p/randomised-s0-machine2.npz"})
    )
    kept = rs.add(path, "randomised", 0, study, rerun="machine2")
    assert kept.name == "randomised-s0-machine2-select.json"
    text = rs.block(study)
    assert "| randomised s0 (rerun machine2) | 94.0 | 91.0 |" in text
    assert "Decision: the randomised eGRU ships as `pretrained:egru-robust`, actor randomised-s0-machine2 (" in text
    # the rerun of a run stressed before its actor was lost is shown, and the run's own record stands
    path.write_text(json.dumps(_record(0.50, {"latency": 0.10, "mass": 0.10})))
    rs.add(path, "plain", 0, study, rerun="machine2")
    text = rs.block(study)
    assert "| plain s0 (rerun machine2), not read by the rule | 50.0 | 10.0 |" in text
    assert "| **plain, mean** | 95.0 | 85.0 |" in text and "Decision: the randomised eGRU ships" in text
    # on the test episodes the reruns stand for seed 0 and the target reads randomised s0's rerun
    path.write_text(json.dumps(_record(0.96, {"latency": 0.80, "mass": 0.90}, seed=TEST_SEED)))
    rs.add(path, "plain", 0, study, rerun="machine2")
    path.write_text(json.dumps(_record(0.95, {"latency": 0.93, "mass": 0.91}, seed=TEST_SEED)))
    rs.add(path, "randomised", 0, study, rerun="machine2")
    text = rs.block(study)
    assert "| plain-s0-machine2 | 96 |" in text and "| randomised-s0-machine2 | 95 |" in text
    assert "Not yet stressed on the test episodes: plain s1, randomised s1." in text
    assert "Target (randomised s0 (rerun machine2), test episodes): met: its largest loss from clean is 4.0" in text
    # the training table lists each rerun's record beside its run's
    assert "| plain s0 (rerun machine2) | finished | 128,000 | 80.0 | 80.0 | trained again |" in text
    assert "| randomised s0 | no record yet |" in text
    # a file in the stress folder named for nothing the study knows is refused by name
    (study / "stress" / "plain-s0-laptop-test.json").write_text(json.dumps(record))
    with pytest.raises(rs.StudyError, match="plain-s0-laptop-test.json: not the record of a run or rerun"):
        rs.block(study)
    (study / "stress" / "plain-s0-laptop-test.json").unlink()
    # two reruns' records with none of the run's own: the study reads one, so it refuses
    _rerun(study, "randomised", 0, label="machine3")
    path.write_text(json.dumps(_record(0.5, {"mass": 0.5})))
    rs.add(path, "randomised", 0, study, rerun="machine3")
    with pytest.raises(rs.StudyError, match=r"randomised s0: select records of reruns \['machine2', 'machine3'\]"):
        rs.block(study)
    # a rerun record named for no run of the study is refused
    (study / "randomised" / "reruns" / "egru-s7-machine2.json").write_text("{}")
    with pytest.raises(rs.StudyError, match="egru-s7-machine2.json: not the rerun record of a run of the study"):
        rs.block(study)


def test_a_pending_decision_says_when_the_missing_records_can_no_longer_change_it(tmp_path):
    study = _plain_arm_stressed(tmp_path)
    # randomised s1 at 87 % clean: with s0 at 100 % the arm's mean could be 93.5 %, within 2 points of 95 %
    _add(study, tmp_path, "randomised", 1, _record(0.87, {"latency": 0.80, "mass": 0.90}))
    text = rs.block(study)
    assert "Decision pending: no selection record yet for randomised s0." in text and "Whatever" not in text
    # at 80 % clean the arm's mean is at most 90 %, more than 2 points below 95 %: no record can ship it
    _add(study, tmp_path, "randomised", 1, _record(0.80, {"latency": 0.99, "mass": 0.99}), replace=True)
    text = rs.block(study)
    assert (
        "Decision pending: no selection record yet for randomised s0. Whatever they hold, the randomised eGRU does "
        "not ship: the randomised arm's mean clean success is at most 90.0 % even if its missing records were "
        "100 %, more than 2 points below the plain arm's lowest possible 95.0 %." in text
    )
    # a score that cannot rise above the plain arm's fixes it too
    _add(study, tmp_path, "randomised", 1, _record(0.95, {"latency": 0.30, "mass": 0.30}), replace=True)
    assert "mean robustness score is at most 65.0 %, not above the plain arm's lowest possible 85.0 %" in rs.block(
        study
    )

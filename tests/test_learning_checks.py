"""benchmarks/learning_checks.py, which CI runs after the suite: a failed check fails the command and
says which criterion failed; the JSON records every check. (The checks themselves train for minutes:
they are the benchmark's, not the suite's.)"""

import json

import pytest

from benchmarks import learning_checks


def test_a_failed_criterion_fails_the_command_and_is_named(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(learning_checks.CHECKS, "toy-vpm", lambda: {"figure": "f", "checks": {"learns": True}})
    monkeypatch.setitem(
        learning_checks.CHECKS, "toy-ugru", lambda: {"figure": "g", "checks": {"learns": False, "stores": True}}
    )
    out = tmp_path / "checks.json"
    assert learning_checks.main(["--only", "toy-vpm", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["passed"] is True
    assert learning_checks.main(["--only", "toy-vpm", "toy-ugru", "--out", str(out)]) == 1
    record = json.loads(out.read_text())
    assert record["passed"] is False and [c["passed"] for c in record["checks"]] == [True, False]
    assert "toy-ugru: FAILED: learns" in capsys.readouterr().out


def test_an_unknown_check_is_refused_by_name(capsys):
    with pytest.raises(SystemExit):
        learning_checks.main(["--only", "toy-sac"])
    assert "invalid choice: 'toy-sac'" in capsys.readouterr().err

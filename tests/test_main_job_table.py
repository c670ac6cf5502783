"""benchmarks/main_job_table.py: rows grouped by budget, commit and evaluation seed, scored from the
per-episode records (cuboids the even episodes, cylinders the odd; an invalid episode is never within
5 cm), the mean and range over training seeds; files it cannot read are refused, naming them."""

import json

import pytest

from benchmarks import main_job_table


def _record(path, eval_seed, success, final, invalid=None, setting="standard", shape="all"):
    invalid = invalid or [False] * len(success)
    spec = {"seed": eval_seed, "setting": setting, "shape": shape}
    path.write_text(
        json.dumps({"spec": spec, "per_episode": {"success": success, "final_distance": final, "invalid": invalid}})
    )


def test_rows_by_budget_commit_and_evaluation_seed(tmp_path):
    # seed 0: both cuboids succeed, no cylinder; its last episode ends at 1 cm but is invalid.
    _record(
        tmp_path / "vpm-cpu-48000-s0-abc1234-seed777.json",
        777,
        [1, 0, 1, 0],
        [0.005, 0.04, 0.001, 0.01],
        invalid=[False, False, False, True],
    )
    _record(tmp_path / "vpm-cpu-48000-s1-abc1234-seed777.json", 777, [1, 1, 1, 1], [0.0] * 4)
    _record(tmp_path / "vpm-cpu-s0-def5678.json", 777, [0, 0, 0, 0], [0.2] * 4)  # the preset's budget
    (tmp_path / "timing-vpm-cpu-48000-abc1234.json").write_text("{}")  # not an evaluation's name: skipped
    rows = main_job_table.collect(tmp_path)
    assert set(rows) == {(48_000, "abc1234", 777), (35_200, "def5678", 777)}
    s0 = rows[48_000, "abc1234", 777][0]
    assert s0 == pytest.approx({"1cm": 50.0, "cuboids": 100.0, "cylinders": 0.0, "5cm": 75.0})
    text = main_job_table.table(rows)
    assert "| 48,000 | abc1234 | 777 | 50 / 100 % (seeds 0, 1) | 75.0 % (50-100) |" in text
    assert "| 35,200 | def5678 | 777 | 0 % (seeds 0) | 0.0 % (0-0) |" in text


@pytest.mark.parametrize(
    "second, message",
    [
        (lambda p: _record(p / "vpm-cpu-s0-abc1234-seed777.json", 777, [1], [0.0]), "a second evaluation"),
        (lambda p: _record(p / "vpm-cpu-s1-abc1234.json", 777, [1], [0.0], setting="difficult"), "standard setting"),
        (lambda p: (p / "vpm-cpu-s1-abc1234.json").write_text('{"spec": {}}'), "not an evaluation record"),
    ],
)
def test_files_it_cannot_read_are_refused_naming_them(tmp_path, second, message):
    _record(tmp_path / "vpm-cpu-s0-abc1234.json", 777, [1], [0.0])
    second(tmp_path)
    with pytest.raises(SystemExit, match=message) as e:
        main_job_table.collect(tmp_path)
    assert "vpm-cpu-s" in str(e.value)


def test_a_folder_without_evaluations_is_refused_naming_it(tmp_path):
    with pytest.raises(SystemExit, match=str(tmp_path)):
        main_job_table.main([str(tmp_path)])

"""benchmarks/batch_speed.py's summary and arguments, on hand-built batch timings (the benchmark itself
trains; nothing is simulated here)."""

import pytest

from benchmarks.batch_speed import main, summary


def _batch(wall, rollout, learn, learning=True):
    return {"env_steps": 0, "wall_s": wall, "rollout_s": rollout, "learn_s": learn, "learning": learning}


def test_the_summary_is_the_median_of_the_batches_that_learn_after_the_first():
    result = {
        "batches": [
            _batch(140.0, 130.0, 10.0),  # the first batch compiles: never in the medians
            _batch(20.0, 20.0, 0.0, learning=False),  # the warm-up learns nothing
            _batch(40.0, 18.0, 22.0),
            _batch(44.0, 20.0, 24.0),
            _batch(50.0, 21.0, 29.0),
        ]
    }
    row = summary("X", result)
    assert row["first_batch_s"] == 140.0
    assert (row["batch_s"], row["rollout_s"], row["learn_s"]) == (44.0, 20.0, 24.0)
    assert row["learning_batches"] == 3


def test_a_measurement_without_a_learning_batch_is_refused():
    with pytest.raises(SystemExit, match="more --batches"):
        summary("X", {"batches": [_batch(140.0, 130.0, 10.0), _batch(20.0, 20.0, 0.0, learning=False)]})


def test_fewer_than_two_batches_is_refused_naming_the_flag(capsys):
    with pytest.raises(SystemExit):
        main(["--batches", "1"])
    assert "--batches must be at least 2" in capsys.readouterr().err


def test_fewer_than_one_device_is_refused_naming_the_flag(capsys):
    with pytest.raises(SystemExit):
        main(["--data-parallel", "0"])
    assert "--data-parallel must be at least 1" in capsys.readouterr().err

"""benchmarks/expert.py refuses step lengths outside (0, 1) before simulating anything."""

import pytest

from benchmarks import expert


@pytest.mark.parametrize("settle", ["0", "1.0", "-0.5"])
def test_a_settle_outside_the_open_unit_interval_is_refused(settle, capsys):
    with pytest.raises(SystemExit) as e:
        expert.main(["--settle", "0.8", settle])
    assert e.value.code == 2
    assert "--settle values must lie in (0, 1)" in capsys.readouterr().err

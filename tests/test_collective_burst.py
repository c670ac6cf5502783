"""benchmarks/collective_burst.py: bad input is refused naming the flag, before any case runs."""

import pytest

from benchmarks import collective_burst


@pytest.mark.parametrize("flag", ["--programs", "--repeats", "--timeout"])
def test_a_count_below_one_is_refused_naming_its_flag(flag, capsys, monkeypatch):
    monkeypatch.setattr(collective_burst, "run_case", lambda *a: pytest.fail("a case ran"))
    with pytest.raises(SystemExit) as e:
        collective_burst.main([flag, "0"])
    assert e.value.code == 2 and f"{flag} must be at least 1, got 0" in capsys.readouterr().err

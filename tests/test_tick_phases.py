"""benchmarks/tick_phases.py: bad input is refused naming the flag, before anything is measured."""

import pytest

from benchmarks import tick_phases


@pytest.mark.parametrize("flag", ["--envs", "--repeats"])
def test_a_count_below_one_is_refused_naming_its_flag(flag, capsys, monkeypatch):
    monkeypatch.setattr(tick_phases, "measure", lambda *a: pytest.fail("a measurement ran"))
    with pytest.raises(SystemExit) as e:
        tick_phases.main([flag, "0"])
    assert e.value.code == 2 and f"{flag} must be >= 1, got 0" in capsys.readouterr().err


def test_the_physics_share_counts_every_phase_of_a_turn_tick():
    ms = {"advance": 40.0, "finish": 6.0, "act": 2.0, "expert": 1.0, "begin": 1.0}
    assert tick_phases.physics_share(ms) == pytest.approx(0.8)
    assert tick_phases.physics_share({**ms, "expert": 11.0}) == pytest.approx(40 / 60)

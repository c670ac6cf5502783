"""benchmarks/substep_chunk.py's schedule model: a group's ticks run until its slowest environment
has spent all its steps, each step rounded up to whole ticks; turns are the ticks on which some
environment's step ended; lockstep is one tick and one turn per step; bad options are refused."""

import numpy as np
import pytest

from benchmarks import substep_chunk


def test_steps_shorter_than_a_tick_cost_a_whole_tick_and_all_end_together():
    asks = np.full((4, 50), 184)
    assert substep_chunk.schedule(asks, 50) == (200, 50)  # 4 ticks a step, every step ends on the same tick
    assert substep_chunk.schedule(asks, 200) == (50, 50)
    assert substep_chunk.schedule(asks, 0) == (50, 50)


def test_the_slowest_environment_sets_the_ticks_and_staggered_ends_add_turns():
    asks = np.array([[120, 120, 120], [60, 60, 60]])
    # chunk 50: env 0 ends its steps on ticks 3, 6, 9; env 1 on 2, 4, 6.
    assert substep_chunk.schedule(asks, 50) == (9, 5)
    assert substep_chunk.schedule(asks, 120) == (3, 3)


@pytest.mark.parametrize("argv", [["--rounds", "0"], ["--chunks", "50", "50"], ["--chunks", "-1"]])
def test_bad_options_are_refused(argv, capsys):
    with pytest.raises(SystemExit) as e:
        substep_chunk.main(argv)
    assert e.value.code == 2
    assert "--rounds must be >= 1" in capsys.readouterr().err

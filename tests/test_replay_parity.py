"""benchmarks/replay_parity.py's bookkeeping: where two trajectories part and which part first (no
simulation here; the benchmark itself runs both simulators)."""

from benchmarks.replay_parity import FLANGE_TOL, OBJECT_TOL, first_over, parity_summary


def _row(geom, obj, flange):
    return {
        "geom_type": geom,
        "object": obj,
        "yaw": [0.0] * len(obj),
        "flange": flange,
        "same_substeps": True,
        "start_diff": 1e-7,
        "object_moved": 0.1,
        "object_first": first_over(obj, OBJECT_TOL),
        "flange_first": first_over(flange, FLANGE_TOL),
    }


def test_first_over_counts_steps_from_one_and_none_when_never_over():
    assert first_over([0.0, 2e-3, 5e-3], OBJECT_TOL) == 2
    assert first_over([0.0, 1e-4], OBJECT_TOL) is None


def test_summary_says_what_parts_first_and_how_many_end_within_a_millimetre():
    rows = [
        _row("box", [0.0, 0.0, 3e-3], [0.0, 5e-4, 5e-4]),  # flange at step 2, object at 3
        _row("box", [0.0, 2e-3, 2e-3], [0.0, 0.0, 0.0]),  # object only
        _row("cylinder", [0.0, 2e-3, 4e-4], [0.0, 2e-4, 0.0]),  # both at step 2; object ends within 1 mm
        _row("cylinder", [0.0, 1e-5, 1e-5], [0.0, 1e-6, 1e-6]),
    ]  # never parts
    s = parity_summary(rows)
    assert s["parts_first"] == {"flange": 1, "object": 1, "same step": 1, "neither": 1}
    assert s["within_1mm"] == 0.5
    assert s["object_parts_at_step"] == {"episodes": 3, "median": 2.0}
    assert s["final_object_diff_m"]["max"] == 3e-3

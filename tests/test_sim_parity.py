"""benchmarks/sim_parity.py's bookkeeping: where one policy's two runs part, what parts first, and the
agreement of outcomes (no simulation here; the benchmark itself runs both simulators)."""

import numpy as np
import pytest

from benchmarks.sim_parity import TOLERANCES, agreement, first_step, parting


def _traj(T=4, latent=0.0, action=0.0, flange=0.0, obj=0.0):
    """A trajectory of T steps; each argument a per-step offset added to a common base."""
    off = lambda v: np.broadcast_to(np.asarray(v, float), (T,))[:, None]  # noqa: E731
    return {
        "latent": np.full((T, 6), 0.3) + off(latent),
        "action": np.full((T, 3), 0.1) + off(action),
        "flange": np.full((T, 2), 0.5) + off(flange),
        "object": np.full((T, 2), 0.6) + off(obj),
    }


def test_first_step_is_one_based_and_none_when_never_over():
    assert first_step([0.0, 2e-3, 5e-3], TOLERANCES["object"]) == 2
    assert first_step([0.0, 1e-4], TOLERANCES["object"]) is None


def test_parting_finds_each_quantity_and_orders_a_tie_as_the_step_runs():
    a = _traj()
    # The object parts at step 2; at step 3 the latent (read first within a step) and the action.
    b = _traj(latent=[0, 0, 0.05, 0.05], action=[0, 0, 0.2, 0.2], obj=[0, 2e-3, 2e-3, 2e-3])
    p = parting(a, b)
    assert p["first"] == {"latent": 3, "action": 3, "flange": None, "object": 2}
    assert p["parts_first"] == "object"
    # Object distance is Euclidean over xy: 2e-3 on both axes is 2.83e-3.
    assert p["diff"]["object"][1] == pytest.approx(2e-3 * np.sqrt(2))
    tie = parting(a, _traj(latent=[0, 0.05, 0.05, 0.05], action=[0, 0.2, 0.2, 0.2], flange=[0, 1, 1, 1]))
    assert tie["parts_first"] == "latent"
    assert parting(a, _traj(flange=1e-6))["parts_first"] == "neither"


def test_agreement_counts_outcomes_correlation_and_parting():
    same = parting(_traj(), _traj())
    late = parting(_traj(), _traj(obj=[0, 0, 0, 5e-3]))
    rows = [
        {"mjx_success": True, "cpu_success": True, "mjx_final": 0.005, "cpu_final": 0.006, "parting": same},
        {"mjx_success": True, "cpu_success": False, "mjx_final": 0.009, "cpu_final": 0.02, "parting": late},
        {"mjx_success": False, "cpu_success": False, "mjx_final": 0.05, "cpu_final": 0.07, "parting": late},
        {"mjx_success": False, "cpu_success": True, "mjx_final": 0.03, "cpu_final": 0.004, "parting": same},
    ]
    s = agreement(rows)
    assert (s["mjx_success"], s["cpu_success"], s["success_agreement"]) == (0.5, 0.5, 0.5)
    expected = np.corrcoef([0.005, 0.009, 0.05, 0.03], [0.006, 0.02, 0.07, 0.004])[0, 1]
    assert s["final_distance_correlation"] == pytest.approx(expected)
    assert s["final_distance_abs_diff_median_m"] == pytest.approx(np.median([0.001, 0.011, 0.02, 0.026]))
    assert s["parts_first"] == {"latent": 0, "action": 0, "flange": 0, "object": 2, "neither": 2}
    assert s["first_step"]["object"] == {"episodes": 2, "median": 4.0}
    assert s["first_step"]["latent"] == {"episodes": 0, "median": None}
    # One episode has no correlation to give.
    assert agreement(rows[:1])["final_distance_correlation"] is None


def test_agreement_by_shape_groups_episodes_and_refuses_unequal_runs():
    from mjx_push.export.metrics import agreement_by_shape

    mjx = {"success": [1.0, 0.0, 1.0, 1.0], "final_distance": [0.005, 0.03, 0.008, 0.002]}
    cpu = [
        {"geom_type": g, "success": s, "final_distance": d}
        for g, s, d in (
            ("box", True, 0.004),
            ("cylinder", True, 0.009),
            ("box", False, 0.02),
            ("cylinder", True, 0.001),
        )
    ]
    got = agreement_by_shape(mjx, cpu)
    assert set(got) == {"all", "cuboids", "cylinders"}
    assert got["all"]["success_agreement"] == 0.5 and got["all"]["episodes"] == 4
    assert got["cuboids"]["mjx_success"] == 1.0 and got["cuboids"]["cpu_success"] == 0.5
    assert got["cylinders"]["success_agreement"] == 0.5
    assert got["cuboids"]["final_distance_abs_diff_median_m"] == pytest.approx(0.0065)
    with pytest.raises(ValueError, match="the MJX evaluation has 4 episodes, the CPU run 3"):
        agreement_by_shape(mjx, cpu[:3])


def test_floor_compares_each_simulator_with_itself_across_two_runs():
    from benchmarks.sim_parity import floor

    def run(noise, mjx, cpu):
        eps = [
            {"episode": i, "mjx_success": m, "mjx_final": 0.02 * (1 - m) + 0.001 * i, "cpu_success": c,
             "cpu_final": 0.02 * (1 - c) + 0.002 * i}
            for i, (m, c) in enumerate(zip(mjx, cpu))
        ]  # fmt: skip
        return {"results": [{"policy": "p", "obs_noise": noise, "analytic": {"episodes": eps}}]}

    a, b = run(0.0, [1, 1, 0, 0], [1, 0, 0, 1]), run(1e-4, [1, 0, 0, 0], [1, 0, 0, 1])
    rows = floor(a, b)
    assert [(r["simulator"], r["success_agreement"]) for r in rows] == [
        ("MJX", 0.75),
        ("CPU MuJoCo, analytic masks", 1.0),
    ]
    assert rows[1]["final_distance_abs_diff_median_m"] == 0.0 and rows[0]["noise"] == [0.0, 1e-4]
    b["results"][0]["analytic"]["episodes"].pop()
    with pytest.raises(ValueError, match="different episodes"):
        floor(a, b)


def test_mask_gap_counts_each_sides_pixels_and_the_shift():
    from benchmarks.mask_gap import gap

    a = np.zeros((8, 8), bool)
    a[2:4, 2:4] = True
    r = a.copy()
    r[2:4, 4] = True  # the render sees one more column
    g = gap(r, a)
    assert (g["render_only"], g["analytic_only"], g["analytic_pixels"]) == (2, 0, 4)
    assert g["iou"] == pytest.approx(4 / 6) and g["centroid_shift"] == pytest.approx([0.0, 0.5])
    with pytest.raises(ValueError, match="non-empty masks"):
        gap(np.zeros((8, 8), bool), a)

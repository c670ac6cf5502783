"""benchmarks.parity_table: docs/parity.md's simulator-parity table is printed from its data, and a
changed number or a missing field is caught."""

import copy
import json

import pytest

from benchmarks import parity_table as pt


def _summary(mjx, cpu, agree, r):
    first = {"flange": {"episodes": 9, "median": 6.0}, "latent": {"episodes": 8, "median": 7.0}}
    parts = {"latent": 3, "action": 0, "flange": 6, "object": 1}
    return {
        "summary": {
            "all": {
                "mjx_success": mjx,
                "cpu_success": cpu,
                "success_agreement": agree,
                "final_distance_correlation": r,
                "final_distance_abs_diff_median_m": 0.0025,
                "first_step": first,
                "parts_first": parts,
            },
            "cuboids": {"success_agreement": agree - 0.1},
            "cylinders": {"success_agreement": agree + 0.1},
        },
        "mask_source_latent_gap": {"median": 0.0, "p95": 0.0231, "max": 0.08, "steps_over_tol": 0.22},
    }


def _data():
    def record(policy, noise, base):
        return {
            "policy": policy,
            "obs_noise": noise,
            "wall_s": {"mjx": 150.0, "analytic": 60.0 + 60 * base, "render": 210.0},
            "analytic": _summary(base, base + 0.02, 0.8, 0.71),
            "render": _summary(base, base - 0.03, 0.75, 0.5),
        }

    return {
        "runs": {
            "obs_noise_0": [record("pretrained:vpm", 0.0, 0.6), record("p/egru-s0.npz", 0.0, 0.9)],
            "obs_noise_policy": [record("pretrained:vpm", 0.0001, 0.5)],
        },
        "tolerances": {"latent": 0.01},
        "floor": [
            {
                "policy": "pretrained:vpm",
                "simulator": "MJX",
                "noise": [0.0, 0.0001],
                "mjx_success": 0.6,
                "cpu_success": 0.5,
                "success_agreement": 0.84,
                "final_distance_correlation": 0.7,
            },
            {
                "policy": "pretrained:vpm",
                "simulator": "CPU MuJoCo, analytic masks",
                "noise": [0.0, 0.0001],
                "mjx_success": 0.62,
                "cpu_success": 0.52,
                "success_agreement": 0.9,
                "final_distance_correlation": 0.8,
            },
        ],
    }


def test_rows_per_policy_and_noise_with_percentages_and_correlations():
    table = pt.table(_data())
    lines = table.splitlines()
    assert lines[2] == "| VPM, none | 60 % | 62 % | 57 % | 80 / 75 % | 0.71 / 0.50 |"
    assert lines[3] == "| VPM, 0.1 mm | 50 % | 52 % | 47 % | 80 / 75 % | 0.71 / 0.50 |"  # a policy's rows together
    assert lines[4].startswith("| eGRU (egru-s0), none | 90 % |")
    assert len(lines) == 5


def test_detail_says_where_runs_part_the_mask_gap_the_floor_and_the_ranges():
    text = pt.detail(_data())
    assert "| VPM, analytic | 70 / 90 % | 2.5 | 3 / 0 / 6 / 1 / 0 | 6 / 7 |" in text
    assert "| VPM, rendered | 65 / 85 % | 2.5 |" in text  # render: agreement 0.75
    assert "| eGRU (egru-s0) | 0.000 / 0.023 / 0.080 | 22 % |" in text
    # where runs part and the mask gap: the noise-off records only (VPM's, eGRU's)
    assert text.count("| VPM, analytic |") == 1 and text.count("| VPM | 0.000") == 1
    assert "| VPM, MJX | 60 / 50 % (none / 0.1 mm) | 84 % | 0.70 |" in text
    # analytic rows gain 2 points, rendered ones lose 3; agreement 75-80 %; floor 84-90 %
    assert text.endswith(
        "Every row: success in CPU MuJoCo within 2-3 points of MJX's, the same outcome in 75-80 % of episodes "
        "(each simulator against itself: 84-90 %), final distances 2.5 mm apart (median); one policy and "
        "setting took 2.5 min in MJX, 1.5-1.9 in CPU MuJoCo with analytic masks, 3.5 with rendered ones."
    )


def test_a_group_names_a_policy_no_longer_shipped_under_its_name_and_gets_its_own_ranges():
    data = copy.deepcopy(_data())
    old = copy.deepcopy(data["runs"]["obs_noise_0"][0])
    old.update(policy="e75f41c:export/pretrained_policies/vpm.npz", group="cpu-long (e75f41c)")
    old["analytic"]["summary"]["all"]["success_agreement"] = 0.5
    data["runs"]["obs_noise_0"].append(old)
    lines = pt.table(data).splitlines()
    assert lines[2].startswith("| VPM, none | 60 %") and lines[-1].startswith("| VPM, cpu-long (e75f41c), none | 60 %")
    with pytest.raises(pt.DataError, match="group 'cpu-long \\(e75f41c\\)' has no floor rows"):
        pt.detail(data)
    data["floor"][0]["group"] = "cpu-long (e75f41c)"
    text = pt.detail(data)
    assert "| VPM, cpu-long (e75f41c), MJX | 60 / 50 % (none / 0.1 mm) | 84 % |" in text
    assert (
        "The cpu-long (e75f41c) rows: success in CPU MuJoCo within 2-3 points of MJX's, the same outcome in 50-75 %"
        in text
    )
    assert "Every row: success in CPU MuJoCo within 2-3 points of MJX's, the same outcome in 75-80 %" in text


def test_missing_fields_and_unknown_settings_are_named():
    bad = copy.deepcopy(_data())
    del bad["runs"]["obs_noise_0"][1]["render"]["summary"]
    with pytest.raises(pt.DataError, match=r"runs.obs_noise_0 \(p/egru-s0.npz\): field 'render.summary.all' missing"):
        pt.table(bad)
    bad = copy.deepcopy(_data())
    bad["runs"]["obs_noise_2"] = []
    with pytest.raises(pt.DataError, match="unknown noise settings \\['obs_noise_2'\\]"):
        pt.table(bad)
    bad = copy.deepcopy(_data())
    del bad["runs"]["obs_noise_0"][0]["render"]["mask_source_latent_gap"]
    with pytest.raises(pt.DataError, match=r"\(pretrained:vpm\): field 'render.mask_source_latent_gap' missing"):
        pt.detail(bad)
    bad = copy.deepcopy(_data())
    bad["floor"] = []
    with pytest.raises(pt.DataError, match="field 'floor' is empty"):
        pt.detail(bad)


def test_check_passes_after_write_and_fails_on_a_changed_number(tmp_path, monkeypatch, capsys):
    data, page = tmp_path / "parity-sim.json", tmp_path / "parity.md"
    data.write_text(json.dumps(_data()))
    page.write_text(
        f"intro\n\n{pt.BEGIN}\n\nold\n\n{pt.END}\n\nmid\n\n{pt.DETAIL_BEGIN}\nold\n{pt.DETAIL_END}\n\nafter\n"
    )
    monkeypatch.setattr(pt, "DATA", data)
    monkeypatch.setattr(pt, "PAGE", page)
    assert pt.main(["--check"]) == 1
    assert pt.main(["--write"]) == 0
    text = page.read_text()
    assert text.startswith("intro\n\n") and text.endswith("\n\nafter\n") and "| VPM, none | 60 % |" in text
    assert "\n\nmid\n\n" in text and "| VPM, MJX | 60 / 50 %" in text
    assert pt.main(["--check"]) == 0
    page.write_text(text.replace("| VPM, none | 60 %", "| VPM, none | 61 %"))
    assert pt.main(["--check"]) == 1
    page.write_text(text.replace("| VPM, MJX | 60 / 50 %", "| VPM, MJX | 60 / 51 %"))
    assert pt.main(["--check"]) == 1
    page.write_text(text.replace(pt.DETAIL_END, ""))
    assert pt.main(["--check"]) == 2
    page.write_text("no markers\n")
    assert pt.main(["--check"]) == 2
    assert "needs one" in capsys.readouterr().err


def test_the_committed_page_is_what_its_data_prints():
    assert pt.main(["--check"]) == 0

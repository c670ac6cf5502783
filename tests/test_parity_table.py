"""benchmarks.parity_table: docs/parity.md's simulator-parity table is printed from its data, and a
changed number or a missing field is caught."""

import copy
import json

import pytest

from benchmarks import parity_table as pt


def _summary(mjx, cpu, agree, r):
    return {
        "summary": {
            "all": {"mjx_success": mjx, "cpu_success": cpu, "success_agreement": agree, "final_distance_correlation": r}
        }
    }


def _data():
    def record(policy, noise, base):
        return {
            "policy": policy,
            "obs_noise": noise,
            "analytic": _summary(base, base + 0.02, 0.8, 0.71),
            "render": _summary(base, base - 0.03, 0.75, 0.5),
        }

    return {
        "runs": {
            "obs_noise_0": [record("pretrained:vpm", 0.0, 0.6), record("p/egru-s0.npz", 0.0, 0.9)],
            "obs_noise_policy": [record("pretrained:vpm", 0.0001, 0.5)],
        }
    }


def test_rows_per_policy_and_noise_with_percentages_and_correlations():
    table = pt.table(_data())
    lines = table.splitlines()
    assert lines[2] == "| VPM, none | 60 % | 62 % | 57 % | 80 / 75 % | 0.71 / 0.50 |"
    assert lines[3] == "| VPM, 0.1 mm | 50 % | 52 % | 47 % | 80 / 75 % | 0.71 / 0.50 |"  # a policy's rows together
    assert lines[4].startswith("| eGRU (egru-s0), none | 90 % |")
    assert len(lines) == 5


def test_missing_fields_and_unknown_settings_are_named():
    bad = copy.deepcopy(_data())
    del bad["runs"]["obs_noise_0"][1]["render"]["summary"]
    with pytest.raises(pt.DataError, match=r"runs.obs_noise_0 \(p/egru-s0.npz\): field 'render.summary.all' missing"):
        pt.table(bad)
    bad = copy.deepcopy(_data())
    bad["runs"]["obs_noise_2"] = []
    with pytest.raises(pt.DataError, match="unknown noise settings \\['obs_noise_2'\\]"):
        pt.table(bad)


def test_check_passes_after_write_and_fails_on_a_changed_number(tmp_path, monkeypatch, capsys):
    data, page = tmp_path / "parity-sim.json", tmp_path / "parity.md"
    data.write_text(json.dumps(_data()))
    page.write_text(f"intro\n\n{pt.BEGIN}\n\nold\n\n{pt.END}\n\nafter\n")
    monkeypatch.setattr(pt, "DATA", data)
    monkeypatch.setattr(pt, "PAGE", page)
    assert pt.main(["--check"]) == 1
    assert pt.main(["--write"]) == 0
    text = page.read_text()
    assert text.startswith("intro\n\n") and text.endswith("\n\nafter\n") and "| VPM, none | 60 % |" in text
    assert pt.main(["--check"]) == 0
    page.write_text(text.replace("| VPM, none | 60 %", "| VPM, none | 61 %"))
    assert pt.main(["--check"]) == 1
    page.write_text("no markers\n")
    assert pt.main(["--check"]) == 2
    assert "needs one" in capsys.readouterr().err


def test_the_committed_page_is_what_its_data_prints():
    assert pt.main(["--check"]) == 0

"""benchmarks.suite_compiles: the plugin records each test's compilations under that test, and the summary
adds them up per test, file, program and worker."""

import json
from pathlib import Path

from benchmarks import suite_compiles

pytest_plugins = ["pytester"]

REPO = Path(__file__).resolve().parents[1]


def test_the_plugin_records_each_tests_compilations_under_that_test(pytester, monkeypatch, tmp_path):
    monkeypatch.setenv("PYTHONPATH", str(REPO))
    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)  # set when this suite runs under xdist
    pytester.makepyfile(
        test_two="""
        import jax, jax.numpy as jnp

        def test_compiles():
            jax.jit(lambda x: jnp.sin(x) * 3)(jnp.ones(5)).block_until_ready()

        def test_compiles_nothing():
            assert 1 + 1 == 2
        """
    )
    out = tmp_path / "records"
    result = pytester.runpytest_subprocess(
        "-p", "benchmarks.suite_compiles", "--compiles-out", str(out), "-p", "no:xdist"
    )
    result.assert_outcomes(passed=2)
    s = suite_compiles.summarise(out)
    tests = {name.split("::")[-1]: t for name, t in s["tests"].items()}
    assert tests["test_compiles"]["compiles"] >= 1 and tests["test_compiles"]["compile_s"] > 0
    assert tests["test_compiles_nothing"]["compiles"] == 0 and tests["test_compiles_nothing"]["wall_s"] >= 0
    assert any(name.startswith("jit(") for name in s["programs"])
    assert list(s["files"]) == ["test_two.py"] and list(s["workers"]) == ["main"]


def test_the_summary_adds_up_phases_tests_files_and_programs(tmp_path, capsys):
    rows = [
        {"worker": "gw0", "test": "tests/a.py::t1", "phase": "setup", "wall_s": 10.0, "compiles": [["jit(step)", 6.0]]},
        {"worker": "gw0", "test": "tests/a.py::t1", "phase": "call", "wall_s": 2.0, "compiles": [["jit(add)", 0.5]]},
        {"worker": "gw1", "test": "tests/b.py::t2", "phase": "call", "wall_s": 7.0, "compiles": [["jit(step)", 4.0]]},
    ]
    for worker in ("gw0", "gw1"):
        lines = [json.dumps(r) for r in rows if r["worker"] == worker]
        (tmp_path / f"{worker}.jsonl").write_text("\n".join(lines) + "\n")
    s = suite_compiles.summarise(tmp_path)
    assert s["tests"]["tests/a.py::t1"]["wall_s"] == 12.0 and s["tests"]["tests/a.py::t1"]["compiles"] == 2
    assert s["files"]["tests/a.py"] == {"wall_s": 12.0, "compile_s": 6.5}
    step = s["programs"]["jit(step)"]
    assert step["compile_s"] == 10.0 and step["count"] == 2 and step["workers"] == ["gw0", "gw1"]
    assert s["workers"]["gw1"] == {"wall_s": 7.0, "compile_s": 4.0}
    suite_compiles.main([str(tmp_path), "--top", "1"])
    printed = capsys.readouterr().out
    assert "tests/a.py::t1" in printed and "tests/b.py::t2" not in printed  # the slowest test only


def test_the_summary_names_a_folder_without_records(tmp_path):
    import pytest

    with pytest.raises(SystemExit, match="no records"):
        suite_compiles.summarise(tmp_path)

"""Where the test suite's time goes: a pytest plugin that records, per test and phase, the wall time and
the XLA compilations it triggered (JAX's own compile events), and a summary of what it recorded.

    python -m pytest -p benchmarks.suite_compiles --compiles-out OUT        # records OUT/<worker>.jsonl
    python -m benchmarks.suite_compiles OUT [--top 25] [--out OUT.json]       # the tables

The suite's time is mostly compilation on CPU, so this is how to find what to share or shrink: the
tests that compile the most, the programs that cost the most in all, and the programs compiled by
more than one test or worker (each xdist worker compiles for itself unless the persistent cache
already holds the program). Programs are named as JAX names them (`jit_step`, `jit_rollout`, ...), so
one name may be several programs (other shapes); the count says how often a name was compiled.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import defaultdict
from pathlib import Path

import pytest

from benchmarks.jax_events import COMPILE_EVENT, LOWER_EVENT, TRACE_EVENT
from benchmarks.output import write_json


class _Recorder:
    def __init__(self, out: Path):
        self.out = out
        self.where = ("(collection)", "setup")
        self.rows: dict[tuple[str, str], dict] = {}

    def row(self) -> dict:
        return self.rows.setdefault(
            self.where, {"test": self.where[0], "phase": self.where[1], "wall_s": 0.0, "compiles": []}
        )

    def on_event(self, event: str, duration: float, **kw) -> None:
        if event == COMPILE_EVENT:
            self.row()["compiles"].append([kw.get("fun_name", "?"), round(duration, 3)])
        elif event in (TRACE_EVENT, LOWER_EVENT):
            r = self.row()
            r["trace_lower_s"] = r.get("trace_lower_s", 0.0) + duration

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_setup(self, item):
        yield from self._timed(item, "setup")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_call(self, item):
        yield from self._timed(item, "call")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_teardown(self, item):
        yield from self._timed(item, "teardown")

    def _timed(self, item, phase):
        self.where = (item.nodeid, phase)
        start = time.perf_counter()
        yield
        self.row()["wall_s"] += time.perf_counter() - start

    def pytest_sessionfinish(self, session):
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        self.out.mkdir(parents=True, exist_ok=True)
        with open(self.out / f"{worker}.jsonl", "w") as f:
            for r in self.rows.values():
                f.write(json.dumps({"worker": worker, **r}) + "\n")


def pytest_addoption(parser):
    parser.addoption("--compiles-out", default=None, help="folder for benchmarks.suite_compiles' records")


def pytest_configure(config):
    out = config.getoption("--compiles-out")
    if not out:
        return
    import jax.monitoring

    recorder = _Recorder(Path(out))
    jax.monitoring.register_event_duration_secs_listener(recorder.on_event)
    config.pluginmanager.register(recorder, "suite_compiles_recorder")


def summarise(folder: Path) -> dict:
    """Per test (phases summed), per program name, and per worker, from a folder of records."""
    paths = sorted(Path(folder).glob("*.jsonl"))
    if not paths:
        raise SystemExit(f"{folder}: no records (*.jsonl); run pytest with -p benchmarks.suite_compiles")
    rows = [json.loads(line) for p in paths for line in p.read_text().splitlines() if line.strip()]
    tests: dict[str, dict] = defaultdict(lambda: {"wall_s": 0.0, "compile_s": 0.0, "trace_lower_s": 0.0, "compiles": 0})
    programs: dict[str, dict] = defaultdict(lambda: {"compile_s": 0.0, "count": 0, "tests": set(), "workers": set()})
    workers: dict[str, dict] = defaultdict(lambda: {"wall_s": 0.0, "compile_s": 0.0})
    files: dict[str, dict] = defaultdict(lambda: {"wall_s": 0.0, "compile_s": 0.0})
    for r in rows:
        t, w, f = tests[r["test"]], workers[r["worker"]], files[r["test"].split("::")[0]]
        for x in (t, w, f):
            x["wall_s"] += r["wall_s"]
        t["trace_lower_s"] += r.get("trace_lower_s", 0.0)
        for name, s in r["compiles"]:
            t["compile_s"] += s
            t["compiles"] += 1
            w["compile_s"] += s
            f["compile_s"] += s
            p = programs[name]
            p["compile_s"] += s
            p["count"] += 1
            p["tests"].add(r["test"])
            p["workers"].add(r["worker"])
    return {
        "tests": dict(tests),
        "programs": {
            k: {**v, "tests": sorted(v["tests"]), "workers": sorted(v["workers"])} for k, v in programs.items()
        },
        "workers": dict(workers),
        "files": dict(files),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--out", type=Path, default=None, help="also write the summary as JSON here")
    a = ap.parse_args(argv)
    s = summarise(a.folder)
    print("worker   wall (s)  compiling (s)")
    for name, w in sorted(s["workers"].items()):
        print(f"{name:8} {w['wall_s']:8.0f}  {w['compile_s']:13.0f}")
    print(f"\nlongest {a.top} files (tests/conftest.py runs the longest first)\n  wall (s)  compiling (s)  file")
    for name, f in sorted(s["files"].items(), key=lambda kv: -kv[1]["wall_s"])[: a.top]:
        print(f"  {f['wall_s']:8.0f}  {f['compile_s']:13.0f}  {name}")
    print(f"\nslowest {a.top} tests (phases summed)\n  wall (s)  compiling (s)  tracing (s)  compiles  test")
    for name, t in sorted(s["tests"].items(), key=lambda kv: -kv[1]["wall_s"])[: a.top]:
        print(f"  {t['wall_s']:8.1f}  {t['compile_s']:13.1f}  {t['trace_lower_s']:11.1f}  {t['compiles']:8d}  {name}")
    print(f"\ncostliest {a.top} programs (all compilations summed)\n  compiling (s)  count  tests  workers  program")
    for name, p in sorted(s["programs"].items(), key=lambda kv: -kv[1]["compile_s"])[: a.top]:
        print(f"  {p['compile_s']:13.1f}  {p['count']:5d}  {len(p['tests']):5d}  {len(p['workers']):7d}  {name}")
    if a.out:
        write_json(a.out, s)


if __name__ == "__main__":
    main()

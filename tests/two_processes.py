"""A data-parallel run as two processes on localhost (`tests/distributed_worker.py`, one CPU device
each, joined through `jax.distributed`): the suite's test of its mechanics and the learning check that
it learns (`benchmarks/learning_checks.py`) start it the same way."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mjx_push import xla

ROOT = Path(__file__).resolve().parents[1]


def worker_env() -> dict:
    """This environment without its host-device count: each worker asks for one CPU device."""
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if not f.startswith(xla.DEVICE_FLAG)]
    return {**os.environ, "XLA_FLAGS": " ".join(flags)}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def toy_run(train):
    """A run configuration of the toy task (tests/toy.py) with the learner `train` (a TrainConfig)."""
    from mjx_push.env import EnvConfig
    from mjx_push.train.config import RunConfig
    from tests.toy import TAU

    return RunConfig(
        agent="vpm", preset="smoke", train=train, env=EnvConfig(episode_length=10, success_tau=TAU), encoder=None
    )


def write_config(path: Path, run_config) -> Path:
    """`run_config` (a RunConfig) as the JSON file both workers read."""
    from mjx_push.train.presets import config_dict

    path.write_text(json.dumps(config_dict(run_config)))
    return path


def launch(run_dir: Path, config: Path, *extra: str, timeout: float = 900) -> None:
    """Train `config` (a JSON run configuration) on the toy task in `run_dir` as two processes, with
    the worker's `extra` options (`--stop-after N`, `--resume`); raises with the processes' output when
    one fails (the other is killed: it would wait for its peer until `jax.distributed` gives up) or
    when they have not both finished within `timeout` seconds (both killed)."""
    port = _free_port()
    cmd = [sys.executable, "-m", "tests.distributed_worker", str(port), "{i}", "2", str(run_dir), str(config), "--toy"]
    with tempfile.TemporaryFile("w+") as log0, tempfile.TemporaryFile("w+") as log1:
        logs = (log0, log1)
        procs = [
            subprocess.Popen(
                [c.format(i=i) for c in cmd] + list(extra),
                cwd=ROOT,
                env=worker_env(),
                stdout=logs[i],
                stderr=subprocess.STDOUT,
                text=True,
            )
            for i in range(2)
        ]
        deadline = time.monotonic() + timeout
        while any(p.poll() is None for p in procs) and time.monotonic() < deadline:
            if any(p.returncode not in (None, 0) for p in procs):
                break
            time.sleep(0.5)
        timed_out = any(p.poll() is None for p in procs) and time.monotonic() >= deadline
        killed = [p.poll() is None for p in procs]
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()
        outs = []
        for log in logs:
            log.seek(0)
            outs.append(log.read())
    if timed_out:
        raise RuntimeError(
            f"the two-process run did not finish in {timeout:.0f} s; both killed. Their output:\n"
            + "\n".join(f"process {i}:\n{out[-2000:]}" for i, out in enumerate(outs))
        )
    # The process that failed on its own first (its peer, killed, only says it was waiting).
    for i in sorted(range(2), key=lambda i: killed[i]):
        if procs[i].returncode != 0:
            peer = "; the other was killed" if killed[1 - i] else ""
            raise RuntimeError(f"process {i} of the two-process run failed{peer}:\n{outs[i][-3000:]}")


def summaries(run_dir: Path) -> list[dict]:
    """Each process's summary of its last launch (the worker writes `summary-<process id>.json`)."""
    return [json.loads((run_dir / f"summary-{i}.json").read_text()) for i in range(2)]

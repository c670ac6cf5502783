"""The comparison's process pool: independent jobs (an agent's training and evaluation, the expert's
row) run in order, or `jobs` at a time in spawned worker processes. Each process splits its
environments over every core, but compilation and the learner's updates run on one core, so on a CPU
two jobs overlap what one leaves idle."""

from __future__ import annotations

import concurrent.futures
import functools
import multiprocessing
from typing import Callable

from mjx_push.errors import ConfigError


def run_jobs(fn: Callable, calls: list[tuple[tuple, dict]], jobs: int) -> list:
    """`fn(*args, **kwargs)` for each call, in order; with jobs > 1 in that many worker processes
    (spawned: JAX is not fork-safe), each compiling its own functions. The first failure cancels the
    jobs not yet started and is raised, naming the call."""
    if jobs < 1:
        raise ConfigError(f"jobs must be >= 1, got {jobs}")
    if jobs == 1:
        return [fn(*args, **kwargs) for args, kwargs in calls]
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=min(jobs, len(calls)), mp_context=ctx) as pool:
        futures = [pool.submit(fn, *args, **kwargs) for args, kwargs in calls]
        for (args, _), fut in zip(calls, futures):
            try:
                fut.result()
            except Exception as e:
                for f in futures:
                    f.cancel()
                raise RuntimeError(f"job {args} failed: {type(e).__name__}: {e}") from e
        return [f.result() for f in futures]


def _log_line(prefix: str, line: str) -> None:
    print(f"{prefix}{line}", flush=True)


def job_log(log: Callable[[str], None], jobs: int, prefix: str) -> Callable[[str], None]:
    """The log a job gets: `log` itself in this process; in a worker, `log` (often a rich console) stays
    behind, so lines go to stdout, prefixed with the job's name (a picklable partial)."""
    return log if jobs == 1 else functools.partial(_log_line, prefix)

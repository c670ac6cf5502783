"""Functions for the worker-pool test of `mjx_push.train.comparison.jobs.run_jobs`: in a module of their own, so the
spawned workers import nothing heavy."""

import os


def pid_and_square(x: int) -> tuple[int, int]:
    if x < 0:
        raise ValueError(f"negative input {x}")
    return os.getpid(), x * x

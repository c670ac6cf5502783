"""The evaluation protocol's metrics (docs/task.md section 7) over a list of CPU MuJoCo episode records,
in the form `mjx-push eval` reports them (`train.evaluate.summarize`): success, reward, overshoot and
distance corrections, and the object-goal distance at reset and at the end, each {"mean", "sem", "n"}
with SEM = sample standard deviation (ddof=1) / sqrt(n), 0 for one episode."""

from __future__ import annotations

import math

import numpy as np

from train.evaluate import DISTANCE_METRICS, METRICS, summarize as summarize_arrays
from mjx_push.errors import ConfigError


def summarize_records(episodes: list[dict]) -> dict:
    """{metric: {"mean", "sem", "n"}} for the paper's METRICS and the DISTANCE_METRICS the episodes hold."""
    if not episodes:
        raise ConfigError("summarize_records needs at least one episode")
    per = {}
    for key in METRICS + DISTANCE_METRICS:
        if key in DISTANCE_METRICS and not all(key in ep for ep in episodes):
            continue
        values = []
        for i, ep in enumerate(episodes):
            if key not in ep:
                raise ConfigError(f"episode {i} has no {key!r} entry (needs {list(METRICS)})")
            v = float(ep[key])
            if not math.isfinite(v):
                raise ConfigError(f"episode {i} has a non-finite {key!r}: {ep[key]!r}")
            values.append(v)
        per[key] = np.asarray(values)
    return summarize_arrays(per)

"""SPEC section 7 metrics over a list of episodes, each with its standard error of the mean.

Each episode is a dict with "success" (bool), "reward" (sum of the sparse rewards), "overshoot" and
"distance" (correction counts). SEM = sample standard deviation (ddof=1) / sqrt(n), 0 for one episode.
"""

from __future__ import annotations

import math

from train.evaluate import sem

METRICS = {"success_rate": "success", "mean_reward": "reward", "overshoot": "overshoot", "distance": "distance"}


def mean_sem(values: list[float]) -> dict:
    """{"mean", "sem", "n"} of `values` (at least one); the SEM of the MJX evaluation protocol."""
    return {"mean": math.fsum(values) / len(values), "sem": sem(values), "n": len(values)}


def summarize(episodes: list[dict]) -> dict:
    """success_rate, mean_reward, overshoot, distance: each {"mean", "sem", "n"}."""
    if not episodes:
        raise ValueError("summarize needs at least one episode")
    out = {}
    for metric, key in METRICS.items():
        values = []
        for i, ep in enumerate(episodes):
            if key not in ep:
                raise ValueError(f"episode {i} has no {key!r} entry (needs {sorted(METRICS.values())})")
            v = float(ep[key])
            if not math.isfinite(v):
                raise ValueError(f"episode {i} has a non-finite {key!r}: {ep[key]!r}")
            values.append(v)
        out[metric] = mean_sem(values)
    return out

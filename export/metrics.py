"""The evaluation protocol's metrics (docs/task.md section 7) over a list of CPU MuJoCo episode records,
in the form `mjx-push eval` reports them (`mjx_push.train.evaluate.summarize`): success, reward, overshoot and
distance corrections, and the object-goal distance at reset and at the end, each {"mean", "sem", "n"}
with SEM = sample standard deviation (ddof=1) / sqrt(n), 0 for one episode."""

from __future__ import annotations

import math

import numpy as np

from mjx_push.train.evaluate import DISTANCE_METRICS, METRICS, summarize as summarize_arrays
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


def agreement(mjx_success, mjx_final, cpu_success, cpu_final) -> dict:
    """How two simulators' runs of the same episodes agree: success in each, the fraction of episodes
    whose outcome is the same, Pearson's correlation of the final object-goal distances (None where
    either side is constant: one episode, or all alike) and the median absolute difference of those
    distances (m)."""
    ms, cs = np.asarray(mjx_success, bool), np.asarray(cpu_success, bool)
    mf, cf = np.asarray(mjx_final, np.float64), np.asarray(cpu_final, np.float64)
    if not (ms.shape == cs.shape == mf.shape == cf.shape) or ms.ndim != 1 or ms.size == 0:
        raise ConfigError(
            f"agreement needs four equal-length 1-D sequences, got {ms.shape}, {mf.shape}, {cs.shape}, {cf.shape}"
        )
    corr = float(np.corrcoef(mf, cf)[0, 1]) if ms.size > 1 and mf.std() > 0 and cf.std() > 0 else None
    return {
        "episodes": int(ms.size),
        "mjx_success": float(ms.mean()),
        "cpu_success": float(cs.mean()),
        "success_agreement": float(np.mean(ms == cs)),
        "final_distance_correlation": corr,
        "final_distance_abs_diff_median_m": float(np.median(np.abs(mf - cf))),
    }


def agreement_by_shape(mjx_per_episode: dict, cpu_records: list[dict]) -> dict:
    """`agreement` of an MJX evaluation's per-episode arrays ("success", "final_distance") and the CPU
    records of the same episodes, in all and per shape group ("cuboids", "cylinders") present."""
    n = len(cpu_records)
    if len(np.asarray(mjx_per_episode["success"])) != n:
        raise ConfigError(
            f"the MJX evaluation has {len(np.asarray(mjx_per_episode['success']))} episodes, the CPU run {n}"
        )
    ms = np.asarray(mjx_per_episode["success"], np.float64) > 0.5
    mf = np.asarray(mjx_per_episode["final_distance"], np.float64)
    cs = np.array([r["success"] for r in cpu_records], bool)
    cf = np.array([r["final_distance"] for r in cpu_records], np.float64)
    geom = np.array([r["geom_type"] for r in cpu_records])
    groups = {"all": np.ones(n, bool), "cuboids": geom == "box", "cylinders": geom == "cylinder"}
    return {g: agreement(ms[m], mf[m], cs[m], cf[m]) for g, m in groups.items() if m.any()}

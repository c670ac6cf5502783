"""Statistics for comparing RL agents over a few training seeds, with bootstrap confidence intervals.

The unit of every claim is the training seed. A score table is an array of shape (runs, tasks): one row
per training seed, one column per task (here per shape: cylinder, square cuboid, rectangular cuboid), e.g.
the success rate within 1 cm of one agent. With the handful of seeds RL training affords, a mean (or
mean +- std) says little about how sure we are; Agarwal et al. 2021, "Deep Reinforcement Learning at the
Edge of the Statistical Precipice" (NeurIPS), recommend reporting instead:

- interval estimates from a *stratified* bootstrap: the runs of each task are resampled with replacement,
  independently per task (and per agent), so a resample never mixes tasks and every task keeps its
  weight;
- the interquartile mean (IQM: the mean of the middle 50% of all run x task scores), which one outlier
  seed cannot drag as it drags the mean, and which is less noisy than the median;
- the probability of improvement P(X > Y): per task, the chance that a run of X scores above a run of Y
  (the Mann-Whitney U statistic over all pairs of runs, ties counting 1/2), averaged over tasks.
- the difference of two agents' per-task means, with an interval that resamples each agent's runs
  independently within each task (two independent samples: the agents' seeds are not paired), for claims
  such as "X scores about 15 points above Y on this task".

The definitions are those of the authors' library rliable (`metrics.aggregate_iqm`,
`metrics.probability_of_improvement`, `library.get_interval_estimates` with its default percentile
intervals and no bootstrap over tasks). rliable 1.2.0 itself is not used: beside this project's pins it
installs but does not import (its dependency arch 7.2 fails against pandas 3), and it would bring pandas,
seaborn and statsmodels for a few lines of NumPy. The bootstrap is written out here rather than taken
from `scipy.stats.bootstrap`, which rejects a sample of one run (one seed per task must still give an
answer: the degenerate interval) and would need each task column passed as a separate sample.

Intervals are percentile intervals (rliable's default): the (1 - confidence)/2 and (1 + confidence)/2
quantiles of the statistic over `reps` resamples. They need no assumption about the shape of the
score distribution, and when every resample gives the same value (identical runs) the interval is that
point, where BCa intervals are undefined. Results are deterministic for a given `seed`. Memory grows as
reps x runs x tasks (x runs of the other agent for the probability of improvement).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, TypeAlias

import numpy as np
import scipy.stats

ScoreTable: TypeAlias = np.ndarray
"""Float scores, shape (runs, tasks): one row per training seed, one column per task."""

Statistic = Literal["mean", "iqm"]

DEFAULT_REPS = 2000
DEFAULT_CONFIDENCE = 0.95


def check_table(scores: ScoreTable, name: str) -> np.ndarray:
    """`scores` as a float array of shape (runs, tasks); a ValueError naming `name` if it is not one
    (not 2-D, no runs or no tasks, NaN or infinite values)."""
    try:
        table = np.asarray(scores, dtype=float)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: not a numeric table of shape (runs, tasks): {e}") from None
    if table.ndim != 2:
        raise ValueError(f"{name}: expected a 2-D table of shape (runs, tasks), got shape {table.shape}")
    if 0 in table.shape:
        raise ValueError(f"{name}: needs at least one run and one task, got shape {table.shape}")
    bad = ~np.isfinite(table)
    if bad.any():
        run, task = np.argwhere(bad)[0]
        raise ValueError(
            f"{name}: {int(bad.sum())} non-finite value(s) (NaN or inf), the first at run {run}, task {task}"
        )
    return table


def _check_bootstrap(reps: int, confidence: float) -> None:
    if isinstance(reps, bool) or not isinstance(reps, (int, np.integer)) or reps < 1:
        raise ValueError(f"reps: expected a positive number of bootstrap resamples, got {reps!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: expected a level strictly between 0 and 1, got {confidence!r}")


def _resample_runs(rng: np.random.Generator, table: np.ndarray, reps: int) -> np.ndarray:
    """`reps` stratified resamples of `table`, shape (reps, runs, tasks): each task's column is filled
    with that task's runs drawn with replacement, by indices drawn independently per task."""
    runs, tasks = table.shape
    rows = rng.integers(0, runs, size=(reps, runs, tasks))
    return np.take_along_axis(table[None], rows, axis=1)


def _percentile_interval(boot: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """The percentile interval of the bootstrap statistics `boot` (resamples on axis 0).

    Identical runs make every resample the table itself, reduced by the same code as the point estimate,
    so every statistic and both quantiles equal the point exactly (no NaN, no rounding-error interval).
    """
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(boot, [tail, 100.0 - tail], axis=0)
    return low, high


def _mean(tables: np.ndarray) -> np.ndarray:
    """Mean over runs and tasks of each table in a stack (..., runs, tasks). Equal to rliable's mean of
    the per-task means, as every task has the same number of runs."""
    return tables.mean(axis=(-2, -1))


def _iqm(tables: np.ndarray) -> np.ndarray:
    """Interquartile mean over runs and tasks of each table in a stack (..., runs, tasks): rliable's
    `scipy.stats.trim_mean(scores, 0.25, axis=None)`, per table."""
    flat = tables.reshape(*tables.shape[:-2], -1)
    return scipy.stats.trim_mean(flat, 0.25, axis=-1)


_STATISTICS: dict[str, Callable[[np.ndarray], np.ndarray]] = {"mean": _mean, "iqm": _iqm}


def _improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) per task for stacks x (..., runs_x, tasks) and y (..., runs_y, tasks): the share of
    (run of x, run of y) pairs where x is higher, a tie counting 1/2 (Mann-Whitney U / (runs_x runs_y))."""
    xs, ys = x[..., :, None, :], y[..., None, :, :]
    wins = (xs > ys) + 0.5 * (xs == ys)
    return wins.mean(axis=(-3, -2))


def per_task_mean(
    scores: ScoreTable, reps: int = DEFAULT_REPS, confidence: float = DEFAULT_CONFIDENCE, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over runs of each task, with a percentile bootstrap interval that resamples that task's runs.

    Returns (mean, low, high), each of shape (tasks,).
    """
    table = check_table(scores, "scores")
    _check_bootstrap(reps, confidence)
    mean = table.mean(axis=0)
    boot = _resample_runs(np.random.default_rng(seed), table, reps).mean(axis=1)
    low, high = _percentile_interval(boot, confidence)
    return mean, low, high


def aggregate(
    scores: ScoreTable,
    statistic: Statistic = "mean",
    reps: int = DEFAULT_REPS,
    confidence: float = DEFAULT_CONFIDENCE,
    seed: int = 0,
) -> tuple[float, float, float]:
    """The mean or interquartile mean ("iqm") over all runs and tasks, with a stratified percentile
    bootstrap interval (runs resampled within each task independently, then aggregated).

    Returns (point, low, high).
    """
    table = check_table(scores, "scores")
    _check_bootstrap(reps, confidence)
    if statistic not in _STATISTICS:
        raise ValueError(f"statistic: expected one of {sorted(_STATISTICS)}, got {statistic!r}")
    reduce = _STATISTICS[statistic]
    point = float(reduce(table))
    boot = reduce(_resample_runs(np.random.default_rng(seed), table, reps))
    low, high = _percentile_interval(boot, confidence)
    return point, float(low), float(high)


def _check_pair(x: ScoreTable, y: ScoreTable) -> tuple[np.ndarray, np.ndarray]:
    """x and y as tables over the same tasks (their numbers of runs may differ)."""
    tx, ty = check_table(x, "x"), check_table(y, "y")
    if tx.shape[1] != ty.shape[1]:
        raise ValueError(
            f"x and y: must have the same number of tasks (columns), got x {tx.shape} and y {ty.shape} "
            "(runs may differ)"
        )
    return tx, ty


def mean_difference(
    x: ScoreTable, y: ScoreTable, reps: int = DEFAULT_REPS, confidence: float = DEFAULT_CONFIDENCE, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per task, the mean of x's runs minus the mean of y's runs, with a percentile bootstrap interval.

    x and y are (runs, tasks) tables over the same tasks; their numbers of runs may differ. Each resample
    draws x's runs and y's runs with replacement, independently of each other and within each task, as
    `probability_of_improvement` does: seed i of x has nothing to do with seed i of y, so no pairing.

    Returns (difference, low, high), each of shape (tasks,).
    """
    tx, ty = _check_pair(x, y)
    _check_bootstrap(reps, confidence)
    difference = tx.mean(axis=0) - ty.mean(axis=0)
    rng = np.random.default_rng(seed)
    boot = _resample_runs(rng, tx, reps).mean(axis=1) - _resample_runs(rng, ty, reps).mean(axis=1)
    low, high = _percentile_interval(boot, confidence)
    return difference, low, high


def probability_of_improvement(
    x: ScoreTable, y: ScoreTable, reps: int = DEFAULT_REPS, confidence: float = DEFAULT_CONFIDENCE, seed: int = 0
) -> dict[str, np.ndarray | float]:
    """P(X > Y): the probability that a run of agent x scores above a run of agent y on the same task.

    x and y are (runs, tasks) tables over the same tasks; their numbers of runs may differ. The interval
    resamples the runs of x and of y independently within each task (stratified, independent samples).

    Returns a dict: `per_task`, `per_task_low`, `per_task_high` (arrays of shape (tasks,)) and
    `aggregate`, `low`, `high` (the mean over tasks and its interval). 0.5 means no difference.
    """
    tx, ty = _check_pair(x, y)
    _check_bootstrap(reps, confidence)
    per_task = _improvement(tx, ty)
    rng = np.random.default_rng(seed)
    boot = _improvement(_resample_runs(rng, tx, reps), _resample_runs(rng, ty, reps))
    task_low, task_high = _percentile_interval(boot, confidence)
    point = float(per_task.mean())
    low, high = _percentile_interval(boot.mean(axis=1), confidence)
    return {
        "per_task": per_task,
        "per_task_low": task_low,
        "per_task_high": task_high,
        "aggregate": point,
        "low": float(low),
        "high": float(high),
    }

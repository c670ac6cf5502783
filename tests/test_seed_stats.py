"""mjx_push.train.comparison.seed_stats: bootstrap intervals, IQM and probability of improvement over training seeds (NumPy
only, no JAX)."""

import ast
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from mjx_push.train.comparison import seed_stats
from mjx_push.train.comparison.seed_stats import (
    aggregate,
    check_table,
    mean_difference,
    per_task_mean,
    probability_of_improvement,
)

REPS = 500  # enough for stable percentiles in these checks, and fast


def _table(runs: int, tasks: int = 3, seed: int = 0) -> np.ndarray:
    """Success-rate-like scores in [0, 1], a different level per task."""
    rng = np.random.default_rng(seed)
    return np.clip(rng.normal(np.linspace(0.3, 0.7, tasks), 0.15, size=(runs, tasks)), 0.0, 1.0)


def test_the_module_imports_no_jax_and_nothing_from_the_project():
    tree = ast.parse(Path(seed_stats.__file__).read_text())
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
    roots = {name.split(".")[0] for name in imported}
    assert not roots & {"jax", "jaxlib", "flax", "optax", "mjx_push", "train", "export"}, roots


def test_intervals_contain_the_mean_and_per_task_means_are_column_means():
    scores = _table(8)
    mean, low, high = per_task_mean(scores, reps=REPS)
    np.testing.assert_allclose(mean, scores.mean(axis=0))
    assert np.all(low < mean) and np.all(mean < high)
    point, lo, hi = aggregate(scores, "mean", reps=REPS)
    assert point == pytest.approx(scores.mean())
    assert lo < point < hi


def test_identical_runs_give_the_point_as_interval_not_nan():
    scores = np.tile([0.1, 0.7, 1.0], (5, 1))  # every seed scored the same
    mean, low, high = per_task_mean(scores, reps=REPS)
    np.testing.assert_array_equal(low, mean)
    np.testing.assert_array_equal(high, mean)
    for statistic in ("mean", "iqm"):
        point, lo, hi = aggregate(scores, statistic, reps=REPS)
        assert lo == point == hi
    one_seed = per_task_mean(scores[:1], reps=REPS)  # one run per task: the degenerate interval
    np.testing.assert_array_equal(one_seed[1], one_seed[2])


def test_iqm_is_scipys_trim_mean_and_ignores_an_outlier_seed():
    scores = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0], [7.0, 100.0]])
    point, low, high = aggregate(scores, "iqm", reps=REPS)
    assert point == pytest.approx(scipy.stats.trim_mean(scores.ravel(), 0.25))
    assert point == pytest.approx(4.5)  # mean of 3, 4, 5, 6: the two lowest and two highest trimmed
    assert low <= point <= high
    assert aggregate(scores, "mean", reps=REPS)[0] == pytest.approx(128.0 / 8)
    table = _table(7, tasks=4)
    assert aggregate(table, "iqm", reps=REPS)[0] == pytest.approx(scipy.stats.trim_mean(table.ravel(), 0.25))


def test_equal_tables_give_probability_of_improvement_one_half():
    scores = _table(6)
    poi = probability_of_improvement(scores, scores.copy(), reps=REPS)
    np.testing.assert_array_equal(poi["per_task"], 0.5)
    assert poi["aggregate"] == 0.5
    assert poi["low"] <= 0.5 <= poi["high"]
    assert np.all(poi["per_task_low"] <= 0.5) and np.all(0.5 <= poi["per_task_high"])


def test_a_dominated_table_gives_one_and_the_reverse_zero():
    y = _table(5)
    x = y.max() + 0.1 + _table(4, seed=1)  # every run of x above every run of y, on every task
    better = probability_of_improvement(x, y, reps=REPS)
    np.testing.assert_array_equal(better["per_task"], 1.0)
    assert better["aggregate"] == better["low"] == better["high"] == 1.0
    worse = probability_of_improvement(y, x, reps=REPS)
    np.testing.assert_array_equal(worse["per_task"], 0.0)
    assert worse["aggregate"] == worse["low"] == worse["high"] == 0.0


def test_probability_of_improvement_by_hand():
    # Task 0: x=[1, 3], y=[2, 2]: pairs 1<2, 1<2, 3>2, 3>2 -> 2/4. Task 1: x=[3, 4], y=[1, 3.5]: 3>1,
    # 3<3.5, 4>1, 4>3.5 -> 3/4. Task 2: x=[1, 2], y=[1, 1]: two ties (1/2 each) and two wins -> 3/4.
    x = np.array([[1.0, 3.0, 1.0], [3.0, 4.0, 2.0]])
    y = np.array([[2.0, 1.0, 1.0], [2.0, 3.5, 1.0]])
    poi = probability_of_improvement(x, y, reps=REPS)
    np.testing.assert_allclose(poi["per_task"], [0.5, 0.75, 0.75])
    assert poi["aggregate"] == pytest.approx(2.0 / 3.0)
    # Runs may differ: x=[1, 2, 3] against y=[2] -> (0 + 1/2 + 1) / 3.
    uneven = probability_of_improvement(np.array([[1.0], [2.0], [3.0]]), np.array([[2.0]]), reps=REPS)
    assert uneven["aggregate"] == pytest.approx(0.5)


def test_mean_difference_is_the_difference_of_column_means_with_independent_resamples():
    x, y = _table(6), _table(4, seed=1)  # runs may differ: the agents' seeds are not paired
    diff, low, high = mean_difference(x, y, reps=REPS)
    np.testing.assert_allclose(diff, x.mean(axis=0) - y.mean(axis=0))
    assert np.all(low < diff) and np.all(diff < high)
    # Every run of x above every run of y: the whole interval above 0; swapped, below.
    above = y.max() + 0.1 + _table(5, seed=2)
    assert np.all(mean_difference(above, y, reps=REPS)[1] > 0)
    assert np.all(mean_difference(y, above, reps=REPS)[2] < 0)
    # Identical runs within each agent: nothing to resample, the interval is the point.
    same_x, same_y = np.tile([0.2, 0.5, 0.9], (5, 1)), np.tile([0.1, 0.5, 1.0], (3, 1))
    diff, low, high = mean_difference(same_x, same_y, reps=REPS)
    np.testing.assert_array_equal(low, diff)
    np.testing.assert_array_equal(high, diff)
    # Resampled independently per agent: the interval is wider than resampling x alone.
    _, x_low, x_high = per_task_mean(x, reps=REPS)
    diff, low, high = mean_difference(x, y, reps=REPS)
    assert np.all(high - low > x_high - x_low)
    first, again = mean_difference(x, y, reps=REPS, seed=7), mean_difference(x, y, reps=REPS, seed=7)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)


def test_mean_difference_refuses_bad_input_by_name():
    good = _table(4)
    with pytest.raises(ValueError, match="y.*non-finite"):
        mean_difference(good, np.where(good > 0.5, np.nan, good))
    with pytest.raises(ValueError, match="x.*at least one run"):
        mean_difference(good[:0], good)
    with pytest.raises(ValueError, match="same number of tasks"):
        mean_difference(good, good[:, :2])
    with pytest.raises(ValueError, match="reps"):
        mean_difference(good, good, reps=0)
    with pytest.raises(ValueError, match="confidence"):
        mean_difference(good, good, confidence=1.0)


def test_resampling_never_mixes_tasks():
    rng = np.random.default_rng(3)
    offsets = np.array([0.0, 10.0, 100.0])  # disjoint ranges: [0, 1], [10, 11], [100, 101]
    scores = offsets + rng.random((6, 3))
    _, low, high = per_task_mean(scores, reps=REPS)
    assert np.all(low >= scores.min(axis=0)) and np.all(high <= scores.max(axis=0))
    # Each task's runs all equal: a stratified resample is the table itself, so the aggregate interval is
    # the point; resampling cells of the whole table would mix 0s and 1s and give a wide interval.
    constant = np.tile([0.0, 1.0], (6, 1))
    assert aggregate(constant, "mean", reps=REPS) == (0.5, 0.5, 0.5)
    poi = probability_of_improvement(constant, constant[:, ::-1], reps=REPS)  # tasks swapped: 1 and 0
    np.testing.assert_array_equal(poi["per_task"], [0.0, 1.0])
    assert poi["aggregate"] == poi["low"] == poi["high"] == 0.5


def _width(scores: np.ndarray, **kwargs) -> float:
    _, low, high = aggregate(scores, "mean", reps=REPS, **kwargs)
    return high - low


def test_more_seeds_narrow_the_interval_and_a_lower_confidence_too():
    many = _table(60)
    few = many[:5]
    assert _width(many) < _width(few) / 2
    assert _width(few, confidence=0.5) < _width(few)
    _, low_few, high_few = per_task_mean(few, reps=REPS)
    _, low_many, high_many = per_task_mean(many, reps=REPS)
    assert np.all(high_many - low_many < high_few - low_few)
    y = _table(60, seed=1)
    poi_few = probability_of_improvement(few, y[:5], reps=REPS)
    poi_many = probability_of_improvement(many, y, reps=REPS)
    assert poi_many["high"] - poi_many["low"] < poi_few["high"] - poi_few["low"]


def test_bad_input_raises_naming_the_argument():
    good = _table(4)
    with pytest.raises(ValueError, match="success_1cm.*2-D"):
        check_table(np.ones(3), "success_1cm")
    with pytest.raises(ValueError, match="scores.*2-D"):
        per_task_mean(np.ones(3))
    with pytest.raises(ValueError, match="scores.*at least one run"):
        aggregate(np.ones((0, 3)))
    nan = good.copy()
    nan[2, 1] = np.nan
    with pytest.raises(ValueError, match="scores.*non-finite.*run 2, task 1"):
        aggregate(nan)
    with pytest.raises(ValueError, match="y.*non-finite"):
        probability_of_improvement(good, np.where(good > 0.5, np.inf, good))
    with pytest.raises(ValueError, match="x.*2-D"):
        probability_of_improvement(good[:, 0], good)
    with pytest.raises(ValueError, match="same number of tasks"):
        probability_of_improvement(good, good[:, :2])
    with pytest.raises(ValueError, match="statistic"):
        aggregate(good, "median")
    with pytest.raises(ValueError, match="reps"):
        per_task_mean(good, reps=0)
    with pytest.raises(ValueError, match="confidence"):
        aggregate(good, confidence=95)


def test_a_fixed_seed_gives_the_same_intervals_and_another_seed_others():
    scores, other = _table(6), _table(6, seed=1)
    runs = [
        lambda seed: per_task_mean(scores, reps=REPS, seed=seed),
        lambda seed: aggregate(scores, "iqm", reps=REPS, seed=seed),
        lambda seed: tuple(probability_of_improvement(scores, other, reps=REPS, seed=seed).values()),
    ]
    for run in runs:
        first, again, another = run(7), run(7), run(8)
        for a, b in zip(first, again):
            np.testing.assert_array_equal(a, b)
        assert any(not np.array_equal(a, c) for a, c in zip(first, another))

"""Correction counters (docs/task.md section 7) on hand-made distance sequences."""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_push import corrections as corr


def run(seq):
    def body(c, d):
        return corr.update(c, d), None

    c, _ = jax.lax.scan(body, corr.Corrections.init(), jnp.asarray(seq, jnp.float32))
    return int(c.overshoot), int(c.distance)


def test_never_moves():
    assert run([0.05] * 20) == (0, 0)


def test_single_overshoot():
    # Approach, enter the goal region, slide out past tau, come back in.
    seq = np.concatenate([np.linspace(0.05, 0.005, 20), np.linspace(0.005, 0.021, 10), np.linspace(0.021, 0.004, 10)])
    over, dist = run(seq)
    assert over == 1
    assert dist == 1  # the distance grew (exit) and later shrank again


def test_oscillation_counts_each_cycle():
    up = np.linspace(0.02, 0.04, 5)
    down = np.linspace(0.04, 0.02, 5)
    seq = np.concatenate([up, down, up, down, up, down])
    assert run(seq) == (0, 3)


def test_dead_band_ignores_jitter():
    # Changes of 1e-5 < eps around tau count nothing, neither overshoot nor distance.
    seq = [0.00999, 0.010005, 0.00999, 0.010005, 0.00999]
    assert run(seq) == (0, 0)


def test_overshoot_needs_clear_exit():
    assert run([0.0099, 0.01001])[0] == 0  # |d - tau| <= eps: not an overshoot
    assert run([0.0099, 0.0101])[0] == 1


def test_first_substep_after_reset_counts_nothing():
    # d_{-1} = +inf: the first distance can neither overshoot nor grow.
    assert run([0.0101]) == (0, 0)


def test_nan_never_counts():
    assert run([0.005, np.nan, 0.02, 0.005]) == (0, 0)

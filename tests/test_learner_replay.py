"""Episode ring buffer and HER "future" relabelling (train/replay.py)."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push.train import replay
from mjx_push.train.config import ReplayConfig

T = 8
TAU = 0.05


def make_episodes(key, n, marker0=0, valid=None):
    """n random episodes; ``action[:, 0, 0]`` holds a marker (marker0, marker0 + 1, ...) to find them."""
    k = jax.random.split(key, 4)
    # A random walk with steps of about TAU, so that relabelled goals give both rewards 0 and -1.
    obj = jnp.cumsum(0.7 * TAU * jax.random.normal(k[0], (n, T + 1, 2)), axis=1)
    action = jnp.zeros((n, T, 3)).at[:, 0, 0].set(marker0 + jnp.arange(n, dtype=jnp.float32))
    return {
        "z_obj": jax.random.normal(k[1], (n, T + 1, 6)),
        "ee_xy": jax.random.normal(k[2], (n, T + 1, 2)),
        "obj_xy": obj,
        "z_goal": jax.random.normal(k[3], (n, 6)),
        "goal_xy": obj[:, -1] + 0.5,
        "action": action,
        "valid": jnp.ones((n,), bool) if valid is None else jnp.asarray(valid),
    }


@pytest.fixture(scope="module")
def sample_fn():
    return jax.jit(replay.sample, static_argnums=2)


@pytest.fixture(scope="module")
def filled(sample_fn):
    buf = replay.init(ReplayConfig(capacity_transitions=16 * T, her_k=4), T, success_tau=TAU)
    buf = replay.add(buf, make_episodes(jax.random.PRNGKey(0), 16))
    return buf, sample_fn(buf, jax.random.PRNGKey(1), 8192)


def test_ring_buffer_wraps_modulo_capacity():
    buf = replay.init(ReplayConfig(capacity_transitions=5 * T + 3), T, success_tau=TAU)  # 5 whole episodes
    assert buf.capacity == 5
    add = jax.jit(replay.add)
    for i in range(3):  # 9 episodes in batches of 3: slots 0-2, 3-4 + 0, 1-3
        buf = add(buf, make_episodes(jax.random.PRNGKey(i), 3, marker0=3 * i))
    assert int(buf.count) == 9
    markers = np.asarray(buf.data["action"][:, 0, 0])
    # Episode j lives in slot j % 5; later episodes overwrote earlier ones in place.
    np.testing.assert_array_equal(markers, [5, 6, 7, 8, 4])
    assert replay.num_valid_transitions(buf) == 5 * T


def test_add_rejects_more_episodes_than_slots():
    buf = replay.init(ReplayConfig(capacity_transitions=2 * T), T, success_tau=TAU)
    with pytest.raises(ValueError, match="cannot add 3 episodes"):
        replay.add(buf, make_episodes(jax.random.PRNGKey(0), 3))


def test_invalid_episodes_are_never_sampled_and_not_stored(sample_fn):
    buf = replay.init(ReplayConfig(capacity_transitions=12 * T), T, success_tau=TAU)
    valid = np.array([1, 0, 0, 1, 0, 1, 1, 0, 0, 0], bool)  # two slots stay empty (invalid)
    eps = make_episodes(jax.random.PRNGKey(0), 10, valid=valid)
    eps["obj_xy"] = jnp.where(jnp.asarray(valid)[:, None, None], eps["obj_xy"], jnp.nan)  # a blown-up sim
    buf = replay.add(buf, eps)
    assert all(np.isfinite(np.asarray(x, np.float64)).all() for x in jax.tree.leaves(buf.data))
    batch = sample_fn(buf, jax.random.PRNGKey(1), 4000)
    e = np.asarray(batch["episode"])
    assert set(np.unique(e)) == set(np.flatnonzero(valid))
    # ...and uniform over the valid ones: 1000 expected each, sd ~27.
    counts = np.bincount(e, minlength=12)[valid.nonzero()[0]]
    assert np.all(np.abs(counts - 1000) < 150), counts


def test_relabelled_goal_comes_from_a_future_observation(filled):
    buf, batch = filled
    t, k, rel = (np.asarray(batch[n]) for n in ("t", "goal_index", "relabelled"))
    e = np.asarray(batch["episode"])
    assert t.min() == 0 and t.max() == T - 1
    assert np.all((k[rel] >= t[rel] + 1) & (k[rel] <= T))
    assert np.all(k[~rel] == -1)
    # Both ends of the future window are used (k = t+1 and k = T).
    assert np.any(k[rel] == t[rel] + 1) and np.any((k[rel] == T) & (t[rel] < T - 1))
    stored = jax.tree.map(np.asarray, buf.data)
    rows = np.flatnonzero(rel)
    np.testing.assert_array_equal(np.asarray(batch["z_goal"])[rows], stored["z_obj"][e[rows], k[rows]])
    np.testing.assert_array_equal(np.asarray(batch["goal_xy"])[rows], stored["obj_xy"][e[rows], k[rows]])
    rows = np.flatnonzero(~rel)
    np.testing.assert_array_equal(np.asarray(batch["z_goal"])[rows], stored["z_goal"][e[rows]])
    np.testing.assert_array_equal(np.asarray(batch["goal_xy"])[rows], stored["goal_xy"][e[rows]])
    # The whole episode and a_t come along for the history features.
    np.testing.assert_array_equal(np.asarray(batch["z_obj"]), stored["z_obj"][e])
    np.testing.assert_array_equal(np.asarray(batch["action"]), stored["action"][e, t])


def test_relabelled_rewards_match_the_ground_truth_goal(filled):
    _, batch = filled
    t = np.asarray(batch["t"])
    obj_next = np.asarray(batch["obj_xy"])[np.arange(t.size), t + 1]
    dist = np.linalg.norm(obj_next - np.asarray(batch["goal_xy"]), axis=-1)
    expected = np.where(dist >= TAU, -1.0, 0.0)
    np.testing.assert_array_equal(np.asarray(batch["reward"]), expected)
    rel = np.asarray(batch["relabelled"])
    # Non-vacuous: relabelled transitions earn both rewards; unrelabelled ones (goal far away) earn -1.
    assert set(np.unique(expected[rel])) == {-1.0, 0.0}
    assert np.all(expected[~rel] == -1.0)
    assert np.all(np.asarray(batch["reward"])[np.asarray(batch["goal_index"]) == t + 1] == 0.0)


def test_relabel_fraction_is_her_k_over_her_k_plus_one(filled, sample_fn):
    _, batch = filled
    frac = float(np.mean(np.asarray(batch["relabelled"])))
    assert abs(frac - 0.8) < 0.02, frac  # sd of the estimate is 0.0044 with 8192 samples
    buf = replay.init(ReplayConfig(capacity_transitions=4 * T, her_k=0), T, success_tau=0.01)
    buf = replay.add(buf, make_episodes(jax.random.PRNGKey(3), 4))
    assert not np.any(np.asarray(sample_fn(buf, jax.random.PRNGKey(4), 512)["relabelled"]))

"""`mjx_push.brax_env.BraxPushEnv` under brax's own training wrappers (`brax.envs.training.wrap`, what
brax's PPO and SAC apply): episodes end at the wrapper's time limit as truncations, restart with fresh
objects and counters, a broken simulation terminates its episode, observations are flat."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs import training as brax_training

from mjx_push import encoder as enc
from mjx_push.brax_env import BraxPushEnv
from mjx_push.env import EnvConfig, PushEnv

L = 3  # the wrapper's episode length
N = 2  # environments


@pytest.fixture(scope="module")
def wrapped():
    cfg = EnvConfig()
    lo = cfg.substeps[0]
    # Short steps: this is about episode bookkeeping, not pushing.
    env = BraxPushEnv(dataclasses.replace(cfg, substeps=(lo, lo + 10), episode_length=L), "box", observation="state")
    w = brax_training.wrap(env, episode_length=env.episode_length)
    return env, jax.jit(w.reset), jax.jit(w.step)


def _random_actions(key):
    return jax.random.uniform(key, (N, 3), minval=-1.0, maxval=1.0)


def test_episodes_truncate_and_restart_with_fresh_objects(wrapped):
    env, reset, step = wrapped
    s = reset(jax.random.split(jax.random.PRNGKey(0), N))
    assert s.obs.shape == (N, env.observation_size) == (N, 10)
    starts = [np.asarray(s.pipeline_state.info["params"].start)]
    key = jax.random.PRNGKey(1)
    dones, truncations, time_outs = [], [], []
    for i in range(3 * L):
        key, k = jax.random.split(key)
        s = step(s, _random_actions(k))
        dones.append(np.asarray(s.done))
        truncations.append(np.asarray(s.info["truncation"]))
        time_outs.append(np.asarray(s.info["time_out"]))
        inner = s.pipeline_state.info
        if (i + 1) % L == 0:  # restarted: a new episode with its own object and counters at zero
            starts.append(np.asarray(s.pipeline_state.info["params"].start))
            np.testing.assert_array_equal(inner["step"], 0)
            np.testing.assert_array_equal(inner["corrections"].distance, 0)
            np.testing.assert_array_equal(inner["corrections"].overshoot, 0)
        else:
            np.testing.assert_array_equal(inner["step"], (i + 1) % L)
        # The observation shows the object being simulated (flat "state": ee, object xy, ...).
        np.testing.assert_allclose(np.asarray(s.obs[:, 2:4]), np.asarray(inner["object_xy"]), atol=1e-6)
    ends = np.array([[float((i + 1) % L == 0)] * N for i in range(3 * L)])
    np.testing.assert_array_equal(np.stack(dones), ends)  # only at the time limit (not every step after)
    np.testing.assert_array_equal(np.stack(truncations), ends)  # and as truncations, not terminations
    np.testing.assert_array_equal(np.stack(time_outs), ends)  # what PPO's bootstrap_on_timeout reads
    starts = np.concatenate(starts)  # 4 episodes x N environments
    assert len({tuple(np.round(x, 6)) for x in starts}) == len(starts)  # every episode a new object
    assert np.isfinite(np.asarray(s.obs)).all()


def test_a_broken_simulation_terminates_its_episode(wrapped):
    _, reset, step = wrapped
    s = reset(jax.random.split(jax.random.PRNGKey(2), N))
    s = step(s, jnp.zeros((N, 3)))
    inner = s.pipeline_state
    data = inner.pipeline_state.replace(qvel=inner.pipeline_state.qvel.at[0, 0].set(jnp.nan))  # env 0 blows up
    s = s.replace(pipeline_state=inner.replace(pipeline_state=data))
    s = step(s, jnp.zeros((N, 3)))
    np.testing.assert_array_equal(np.asarray(s.done), [1.0, 0.0])  # a termination, before the time limit
    np.testing.assert_array_equal(np.asarray(s.info["truncation"]), [0.0, 0.0])
    np.testing.assert_array_equal(np.asarray(s.info["time_out"]), [0.0, 0.0])
    np.testing.assert_array_equal(np.asarray(s.pipeline_state.info["step"]), [0, 2])  # env 0 restarted
    assert not bool(s.pipeline_state.info["episode_invalid"][0])
    assert np.isfinite(np.asarray(s.obs)).all() and np.isfinite(np.asarray(s.pipeline_state.pipeline_state.qpos)).all()


def test_flat_observation_modes():
    key = jax.random.PRNGKey(0)
    params = enc.load()
    for mode, size in (("latent", 14), ("state", 10), ("mask", 2 + 2 * 64 * 64)):
        env = BraxPushEnv(EnvConfig(), "cylinder", observation=mode, encoder_params=params)
        assert env.observation_size == size
        assert jax.eval_shape(env.reset, key).obs.shape == (size,)  # traced, not compiled
    with pytest.raises(ValueError, match="observation must be one of"):
        BraxPushEnv(observation="pixels")
    with pytest.raises(ValueError, match="reward must be one of"):
        BraxPushEnv(reward="shaped")


def test_brax_evaluation_wrapper_accepts_the_environment():
    # brax's trainers evaluate through EvalWrapper, which adds metrics of its own (traced, not compiled).
    env = BraxPushEnv(EnvConfig(), "box", observation="state")
    w = brax_training.EvalWrapper(brax_training.wrap(env, episode_length=L))
    state = jax.eval_shape(w.reset, jax.random.split(jax.random.PRNGKey(0), N))
    after = jax.eval_shape(w.step, state, jnp.zeros((N, 3)))
    assert set(after.metrics) == {"success", "distance", "reward"} and after.obs.shape == (N, 10)


def test_push_env_under_brax_wrappers_is_refused_with_a_pointer():
    w = brax_training.wrap(PushEnv(EnvConfig(), "box"), episode_length=L)
    keys = jax.random.split(jax.random.PRNGKey(0), N)
    state = jax.eval_shape(w.reset, keys)
    with pytest.raises(ValueError, match="BraxPushEnv"):
        jax.eval_shape(w.step, state, jnp.zeros((N, 3)))


def test_brax_trainers_find_device_put_replicated():
    # brax 0.14.2's PPO and SAC call jax.device_put_replicated, which jax 0.10 removed; importing
    # mjx_push.brax_env restores an equivalent (the brax benchmark runs the trainers themselves).
    devices = jax.local_devices()[:1]
    out = jax.device_put_replicated({"w": jnp.arange(3.0)}, devices)
    assert out["w"].shape == (1, 3)
    np.testing.assert_array_equal(np.asarray(out["w"][0]), [0.0, 1.0, 2.0])

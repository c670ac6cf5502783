"""The jitted collect + update loop and its driver (train/loop.py) on the toy task (tests/toy.py):
what runs when, what is stored and selected. Whether the loop learns is checked by
`benchmarks/learning_checks.py` (toy-vpm, toy-ugru), which CI runs after the suite."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import xla
from mjx_push.train.config import ReplayConfig
from mjx_push.train.adapter import EnvAdapter
from mjx_push.train.loop import Runner, make_train, train as run_train
from tests.toy import TAU, make_toy, toy_config


@pytest.fixture(scope="module", params=[("vpm", 1600), ("ugru", 1920)], ids=["vpm", "ugru"])
def learned(request):
    """The learning check's schedule (benchmarks/learning_checks.py) on narrow networks: the loop's
    mechanics do not need the task learned."""
    kind, steps = request.param
    cfg = toy_config(kind, steps, hidden=(32, 32), batch_size=32)
    runner = Runner(make_train(cfg, make_toy(success_tau=TAU)))
    state, history = run_train(jax.random.PRNGKey(0), cfg, runner.trainer.adapter, runner=runner)
    return cfg, runner.trainer, state, history, runner.evaluate


def test_best_params_are_selected_by_mean_reward(learned):
    cfg, trainer, state, history, evaluate = learned
    evals = [h for h in history if "eval/mean_reward" in h]
    # Every 800 env steps, and after the last iteration.
    steps = cfg.loop.total_env_steps
    assert [h["env_steps"] for h in evals] == sorted(set(range(800, steps + 1, 800)) | {steps})
    best = max(h["eval/mean_reward"] for h in evals)
    assert float(state.best_eval_reward) == pytest.approx(best)
    # The kept params reproduce that score on the (fixed) evaluation episodes.
    again = evaluate(state.best_actor_params, trainer.eval_key)
    assert float(again["mean_reward"]) == pytest.approx(best)


def test_warmup_then_updates_per_batch(learned):
    cfg, trainer, state, history, _ = learned
    per_iter = cfg.loop.updates_per_iteration(trainer.adapter.episode_len)
    assert per_iter == 80
    learning = [h["learning"] for h in history]
    first = learning.index(True)
    # Random actions and no updates until 480 env steps (6 batches of 80), then 80 updates per batch.
    assert first == 5 and not any(learning[:first]) and all(learning[first:])
    expected_updates = [max(0, i - first + 1) * per_iter for i in range(len(history))]
    assert [h["updates"] for h in history] == expected_updates
    assert [h["env_steps"] for h in history] == [80 * (i + 1) for i in range(len(history))]
    assert int(state.sac.step) == (len(history) - first) * per_iter


def nan_toy(invalid_prob=0.1):
    """The toy, but a step flagged invalid also returns NaN observations (a blown-up simulation)."""
    toy = make_toy(success_tau=TAU, invalid_prob=invalid_prob)

    def step(state, action):
        state, obs, invalid = toy.step(state, action)
        obs = jax.tree.map(lambda x: jnp.where(invalid[:, None], jnp.nan, x), obs)
        return state, obs, invalid

    return EnvAdapter(reset=toy.reset, step=step, success_tau=TAU, episode_len=toy.episode_len)


@pytest.fixture(scope="module")
def small():
    cfg = toy_config("vpm", 400, hidden=(32, 32), batch_size=16, warmup_env_steps=0, utd=0.25, eval_every_env_steps=160)
    adapter = nan_toy()
    return cfg, adapter, make_train(cfg, adapter)


def test_invalid_episodes_do_not_poison_learning(small):
    cfg, adapter, trainer = small
    state, history = run_train(jax.random.PRNGKey(1), cfg, adapter, trainer=trainer)
    invalid = np.mean([h["train/invalid_rate"] for h in history])
    assert 0.3 < invalid < 0.9  # 1 - 0.9**10 = 65 % of episodes hit an invalid step
    valid_episodes = round(sum((1 - h["train/invalid_rate"]) * 8 for h in history))
    assert int(np.sum(state.buffer.data["valid"])) == history[-1]["replay/valid_episodes"] == valid_episodes
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(state.buffer.data))
    # Updates start once 16 valid transitions are stored, 20 per batch from then on.
    learning = sum(h["learning"] for h in history)
    assert learning >= 3 and int(state.sac.step) == learning * 20
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(state.sac))
    assert all(np.isfinite(h["sac/critic_loss"]) for h in history)


def test_resuming_gives_the_same_result(small):
    cfg, adapter, trainer = small
    full, _ = run_train(jax.random.PRNGKey(2), cfg, adapter, trainer=trainer)
    stop_at_160 = lambda s, m: m["env_steps"] >= 160  # noqa: E731
    part, h1 = run_train(jax.random.PRNGKey(2), cfg, adapter, callback=stop_at_160, trainer=trainer)
    assert len(h1) == 2
    resumed, h2 = run_train(None, cfg, adapter, trainer=trainer, state=part)
    assert len(h2) == 3
    jax.tree.map(np.testing.assert_array_equal, resumed.sac, full.sac)
    jax.tree.map(np.testing.assert_array_equal, resumed.best_actor_params, full.best_actor_params)


def test_the_task_facts_are_the_environments():
    """The learner's success radius (its rewards) and episode length are the adapter's, and the checks
    that need them name the learner's field."""
    trainer = make_train(toy_config("vpm", 400), make_toy(success_tau=0.01, episode_len=7))
    buffer = trainer.init(jax.random.PRNGKey(0)).buffer
    assert (buffer.success_tau, buffer.episode_len) == (0.01, 7)
    curriculum = dataclasses.replace(
        toy_config("vpm", 400),
        replay=ReplayConfig(capacity_transitions=20_000, curriculum_tau=0.03, curriculum_env_steps=8),
    )
    with pytest.raises(
        ValueError, match=r"replay\.curriculum_tau must be None or a number >= the task's success radius \(0\.05\)"
    ):
        make_train(curriculum, make_toy(success_tau=0.05))
    with pytest.raises(
        ValueError,
        match=r"replay\.capacity_transitions must be at least loop\.num_envs \* the task's episode length = 24000",
    ):
        make_train(toy_config("vpm", 400), make_toy(success_tau=TAU, episode_len=3000))


@pytest.mark.parametrize("kind", ["vpm", "ugru"])
def test_scheduled_rollout_gives_the_lockstep_episodes(kind):
    """Steps of 1..8 substeps advanced 3 at a time: environments finish their steps at different
    ticks, yet every episode (observations, actions, invalid flags) is the lockstep one."""
    cfg = toy_config(kind, 160, num_envs=6)
    lock = make_train(cfg, make_toy(success_tau=TAU, episode_len=7, invalid_prob=0.05))
    sched = make_train(
        cfg, make_toy(success_tau=TAU, episode_len=7, invalid_prob=0.05, substep_chunk=3, max_substeps=8)
    )
    actor = lock.init(jax.random.PRNGKey(1)).sac.actor_params
    for random_actions, deterministic in ((True, False), (False, False), (False, True)):
        args = (actor, jax.random.PRNGKey(5), jnp.asarray(random_actions), jnp.asarray(deterministic))
        a, _ = jax.jit(lock.rollout)(*args)
        b, _ = jax.jit(sched.rollout)(*args)
        jax.tree.map(lambda x, y: np.testing.assert_allclose(x, y, rtol=0, atol=1e-6), a, b)
        if random_actions:  # the step lengths really differed (1 to 8 substeps)
            assert np.ptp(np.floor((np.asarray(a["action"][..., 2]) + 1) / 2 * 7)) >= 5


def test_substep_scheduler_rejects_a_bad_chunk():
    with pytest.raises(ValueError, match="substep chunk must be a positive integer"):
        make_toy(substep_chunk=-2)


def test_selection_keeps_the_best_reward_and_gives_ties_to_the_newer_params():
    trainer = make_train(toy_config("vpm", 160), make_toy(success_tau=TAU))
    select = jax.jit(trainer.select)
    ts = trainer.init(jax.random.PRNGKey(0))

    def evaluated(ts, steps, reward, success):
        ts = ts.replace(env_steps=jnp.asarray(steps, jnp.int32))
        ts, m = select(
            ts,
            {
                "mean_reward": jnp.float32(reward),
                "success_rate": jnp.float32(success),
                "invalid_rate": jnp.float32(0.0),
            },
        )
        return ts, bool(m["eval/improved"])

    ts, improved = evaluated(ts, 100, -10.0, 0.0)
    assert improved and int(ts.best_env_steps) == 100
    ts, improved = evaluated(ts, 200, -10.0, 0.0)  # tie: the newer params win
    assert improved and int(ts.best_env_steps) == 200
    ts, improved = evaluated(ts, 300, -12.0, 0.5)  # lower reward loses, whatever its success
    assert not improved and int(ts.best_env_steps) == 200
    ts, improved = evaluated(ts, 400, -9.0, 0.2)
    assert improved and float(ts.best_eval_success) == pytest.approx(0.2)
    ts, improved = evaluated(ts, 500, -9.0, 0.1)  # same reward, lower success: kept the older
    assert not improved and int(ts.best_env_steps) == 400


@pytest.mark.parametrize("devices", [1, 2], ids=["one-device", "data-parallel"])
def test_the_updates_compile_with_the_physics_free_options(monkeypatch, devices):
    """The learner's updates (one device, or split over devices) are compiled with
    mjx_push.xla.physics_free_options and the rollout without: an option XLA does not know, put there,
    stops the updates' compilation and nothing else."""
    assert len(jax.devices()) >= devices, "the suite runs with a host device per core (2 on its machines)"
    monkeypatch.setattr(xla, "physics_free_options", lambda: {"xla_no_such_option_of_this_test": True})
    cfg = toy_config("vpm", 160, hidden=(16,), batch_size=16, data_parallel=devices)
    runner = Runner(make_train(cfg, make_toy(success_tau=TAU)))
    ts = runner.init(jax.random.PRNGKey(0))
    with pytest.raises(Exception, match="xla_no_such_option_of_this_test") as caught:
        runner.iteration(ts)
    assert "rollout" not in "".join(f.name for f in caught.traceback)  # the rollout compiled and ran

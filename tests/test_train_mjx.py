"""End to end on the MJX scene: masks -> encoder -> SAC + HER -> checkpoint and policy, at a tiny size
(2 environments, 3-step episodes) so that compilation, not simulation, is the cost."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import encoder as enc
from tests.helpers import tiny_run_config
from mjx_push.train.runs import run as run_mod
from mjx_push.train.push_task import make_push_adapter, run_adapter


def test_adapter_latents_are_the_encoder_of_the_masks(encoder_file):
    cfg = tiny_run_config("vpm", encoder_file)
    params = enc.load(encoder_file)
    adapter = make_push_adapter(cfg.env, params)

    @jax.jit
    def reset(key):  # one compile: the adapter's outputs and the environment state they came from
        s, obs, info = adapter.reset(key, 2)
        return obs, info, s.obs["object_mask"], s.obs["goal_mask"], s.info["object_xy"], s.info["goal_xy"]

    obs, info, object_mask, goal_mask, object_xy, goal_xy = reset(jax.random.PRNGKey(3))
    assert object_mask.sum() > 0 and goal_mask.sum() > 0
    np.testing.assert_allclose(obs["z_obj"], enc.encode(params, object_mask), atol=1e-5)
    np.testing.assert_allclose(info["z_goal"], enc.encode(params, goal_mask), atol=1e-5)
    np.testing.assert_array_equal(obs["obj_xy"], object_xy)
    np.testing.assert_array_equal(info["goal_xy"], goal_xy)
    assert obs["ee_xy"].shape == (2, 2) and jnp.all(jnp.isfinite(obs["ee_xy"]))
    assert not np.allclose(obs["z_obj"], info["z_goal"])  # start and goal differ


def test_nan_in_a_running_environment_drops_the_episode_and_training_continues(encoder_file, tmp_path):
    """NaN injected into environment 0's joint velocities at the second step of every episode: the
    environment detects it (and puts the episode's initial state back), the learner stores the episode
    as invalid and never samples it, and training runs to the end on environment 1's episodes."""
    import csv
    import dataclasses

    from mjx_push import objects
    from mjx_push.batch import BatchState

    cfg = tiny_run_config("vpm", encoder_file)
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, objects=objects.ObjectConfig(shape="cuboid")))
    base = make_push_adapter(cfg.env, enc.load(encoder_file), substep_chunk=0)

    def step(s: BatchState, action):
        (g,) = s.groups  # one shape group: cuboids
        hit = (jnp.arange(g.reward.shape[0]) == 0) & (g.info["step"] == 1)
        qvel = jnp.where(hit[:, None], jnp.nan, g.pipeline_state.qvel)
        return base.step(BatchState((g.replace(pipeline_state=g.pipeline_state.replace(qvel=qvel)),)), action)

    summary, state = run_mod.run(cfg, tmp_path / "nan", adapter=dataclasses.replace(base, step=step))
    assert summary["env_steps"] == cfg.train.loop.total_env_steps and summary["updates"] > 0  # it went on
    data = jax.device_get(state.buffer.data)
    np.testing.assert_array_equal(data["valid"][:4], [False, True, False, True])  # env 0's episodes dropped
    assert np.isfinite(data["z_obj"][:4]).all() and np.isfinite(data["obj_xy"][:4]).all()  # nothing leaked
    assert all(np.isfinite(x).all() for x in jax.tree.leaves(jax.device_get(state.sac)))
    with (tmp_path / "nan" / "metrics.csv").open() as f:
        assert [float(r["train/invalid_rate"]) for r in csv.DictReader(f)] == [0.5, 0.5]
    assert (tmp_path / "nan" / "best_policy.msgpack").is_file()


def test_push_adapter_rejects_a_negative_substep_chunk():
    from mjx_push.env import EnvConfig

    with pytest.raises(ValueError, match=r"substep_chunk must be an integer >= 0 \(0: lockstep\), got -1"):
        make_push_adapter(EnvConfig(), None, -1)


def test_batches_after_the_first_compile_nothing_and_evaluate_the_protocols_episodes(encoder_file):
    """The tiny eGRU run's configuration as `run` builds it (so its programs are the fixture's): the
    environments are split over the host devices, yet the learner and the next rollout reuse the first
    batch's programs (argument placements that changed per batch once recompiled the rollout), and the
    in-run evaluation runs the protocol's episodes in their order. Whether an actor learns the expert's
    pushes on this scene: benchmarks/learning_checks.py (scene-imitation), run by CI."""
    from mjx_push.train.episodes import EvalSpec, episode_objects
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import DEFAULT_SUBSTEP_CHUNK, EVAL_SHAPE

    cfg = tiny_run_config("egru", encoder_file)
    adapter = make_push_adapter(cfg.env, enc.load(encoder_file), DEFAULT_SUBSTEP_CHUNK, cfg.expert)
    runner = Runner(make_train(cfg.train, adapter))
    state = runner.init(jax.random.PRNGKey(cfg.train.loop.seed))
    untrained = jax.tree.map(jnp.copy, state.sac.actor_params)
    compiles = []  # programs compiled (or loaded from the cache) after the first batch

    def on_event(event, secs, **kwargs):
        if ("backend_compile" in event and secs > 0.5) or "cache_retrieval" in event:
            compiles.append((event, round(secs, 2)))

    T = cfg.env.episode_length
    history = []
    for i in range(cfg.train.loop.num_iterations(T)):
        if i == 1:
            jax.monitoring.register_event_duration_secs_listener(on_event)
        state, m = runner.iteration(state)
        history.append(m)
    jax.monitoring.unregister_event_duration_listener(on_event)
    assert len(history) == 2 and bool(history[-1]["learning"])  # the second batch ran updates
    assert runner.trainer.rollout_mesh is None or runner.trainer.rollout_mesh.size == len(jax.devices())
    assert compiles == [], compiles

    ev = runner.evaluate(untrained)
    loop = cfg.train.loop
    spec = EvalSpec(setting=loop.eval_setting, shape=EVAL_SHAPE[cfg.env.objects.shape], seed=loop.eval_seed)
    assert cfg.env.objects.shape == "any" and loop.eval_episodes == 2  # cuboid episode 0, cylinder episode 1
    want = [episode_objects(spec, cfg.env.objects, g, np.array([i]))[0] for i, g in enumerate(("box", "cylinder"))]
    start = [np.linalg.norm(w.start[0, :2] - w.goal[0, :2]) for w in want]
    np.testing.assert_allclose(ev["episode_start_distance"], start, rtol=1e-5)


def test_a_data_parallel_runs_adapter_keeps_each_batch_on_one_device():
    """`run_adapter`: a one-device run splits a batch over the host devices, a data-parallel run keeps
    each device's share whole on it (what `make_train` asks of it)."""
    import dataclasses

    if len(jax.devices()) < 2:
        pytest.skip("one device: MJX_PUSH_CPU_DEVICES=1 or a one-core machine, nothing to split")
    cfg = tiny_run_config("vpm", None)
    split = dataclasses.replace(cfg.train.loop, data_parallel=2)
    per_device = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, loop=split))
    assert run_adapter(cfg, None).mesh(4) is not None
    assert run_adapter(per_device, None).mesh(4) is None


def test_a_batch_split_over_the_devices_by_whole_episodes_runs_one_devices_episodes(encoder_file):
    """A one-device run on several host devices splits each batch by whole episodes (each device runs
    its share's episodes as a batch of its own, `make_split_collect`): its training episodes (expert
    and agent alike) and its evaluation episodes are those of the same batch run on one device, in the
    batch's order. Four environments: two cuboids and two cylinders, one of each per device."""
    import dataclasses

    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.rollout import make_collect

    if len(jax.devices()) < 2:
        pytest.skip("one device: MJX_PUSH_CPU_DEVICES=1 or a one-core machine, nothing to split")
    cfg = tiny_run_config("egru", encoder_file)
    loop = dataclasses.replace(cfg.train.loop, num_envs=4, eval_episodes=4)
    cfg = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, loop=loop))
    params = enc.load(encoder_file)
    runner = Runner(make_train(cfg.train, make_push_adapter(cfg.env, params, expert_config=cfg.expert)))
    assert runner.trainer.rollout_mesh.size == 2 and runner.trainer.rollout_split == "episodes"
    state = runner.init(jax.random.PRNGKey(1))
    one = make_push_adapter(cfg.env, params, expert_config=cfg.expert, max_devices=1)
    collect = make_collect(cfg.train, one, runner.trainer.networks)
    on_one = jax.jit(lambda p, k, e, ep: collect(p, k, 4, jnp.asarray(False), jnp.asarray(False), e, ep))
    expert = jnp.asarray([True, False, False, True])
    chunk = runner.eval_chunks()[0]
    for use in (False, True):  # training's fresh episodes, then the protocol's
        ep = {**chunk, "use": np.asarray(use)}
        split, split_stats = runner.rollout(state.sac.actor_params, jax.random.PRNGKey(5), False, False, expert, ep)
        whole, whole_stats = on_one(state.sac.actor_params, jax.random.PRNGKey(5), expert, ep)
        assert split.keys() == whole.keys() and split_stats.keys() == whole_stats.keys()
        for k in whole:
            np.testing.assert_allclose(np.asarray(split[k]), np.asarray(whole[k]), atol=1e-6, err_msg=k)
        for k in whole_stats:
            np.testing.assert_allclose(np.asarray(split_stats[k]), np.asarray(whole_stats[k]), atol=1e-6, err_msg=k)
        np.testing.assert_array_equal(split["demo"], expert)
    assert not np.allclose(split["goal_xy"][0], split["goal_xy"][2])  # different episodes, not one repeated


def test_the_device_layout_gives_each_device_a_slice_of_every_group():
    from mjx_push.train.rollout import device_layout

    assert device_layout((4, 4), 2).tolist() == [0, 1, 4, 5, 2, 3, 6, 7]
    assert device_layout((6,), 3).tolist() == [0, 1, 2, 3, 4, 5]
    assert device_layout((2, 2), 1).tolist() == [0, 1, 2, 3]
    with pytest.raises(ValueError, match=r"groups \(3, 3\) do not split evenly over 2 devices"):
        device_layout((3, 3), 2)


def test_an_adapter_with_a_function_replaced_has_only_its_physics_split():
    """The whole-episode split runs the push task's own one-device twin, so a copy of the adapter with
    its step (or reset, scheduler, expert) replaced keeps the physics-only split, which runs the copy's
    functions (test_nan_in_a_running_environment... relies on it); nothing is compiled here."""
    import dataclasses

    from mjx_push.train.loop import make_train

    if len(jax.devices()) < 2:
        pytest.skip("one device: MJX_PUSH_CPU_DEVICES=1 or a one-core machine, nothing to split")
    cfg = tiny_run_config("vpm", None)
    cfg = dataclasses.replace(
        cfg, train=dataclasses.replace(cfg.train, loop=dataclasses.replace(cfg.train.loop, num_envs=4))
    )
    adapter = make_push_adapter(cfg.env, None)
    wrapped = dataclasses.replace(adapter, step=lambda s, a: adapter.step(s, a))
    assert make_train(cfg.train, adapter).rollout_split == "episodes"
    assert make_train(cfg.train, wrapped).rollout_split == "physics"
    assert make_train(cfg.train, make_push_adapter(cfg.env, None, max_devices=1)).rollout_split is None

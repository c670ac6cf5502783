"""End to end on the MJX scene: masks -> encoder -> SAC + HER -> checkpoint and policy, at a tiny size
(2-4 environments, 3-step episodes) so that compilation, not simulation, is the cost. The tests that
run the tiny eGRU run's own programs live beside it, in tests/test_tiny_egru_run.py."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import devices, encoder as enc
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

    cfg = tiny_run_config("vpm", encoder_file, num_envs=2)
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


def test_the_device_layout_gives_each_device_a_slice_of_every_group():
    from mjx_push.train.rollout import device_layout

    assert device_layout((4, 4), 2).tolist() == [0, 1, 4, 5, 2, 3, 6, 7]
    assert device_layout((6,), 3).tolist() == [0, 1, 2, 3, 4, 5]
    assert device_layout((2, 2), 1).tolist() == [0, 1, 2, 3]
    with pytest.raises(ValueError, match=r"groups \(3, 3\) do not split evenly over 2 devices"):
        device_layout((3, 3), 2)


def test_an_adapter_with_a_function_replaced_has_only_its_physics_split():
    """The whole-episode splits run the push task's own one-device twins (one per shape group, or one
    of the whole batch for a one-shape run), so a copy of the adapter with its step (or reset,
    scheduler, expert) replaced keeps the physics-only split, which runs the copy's functions
    (test_nan_in_a_running_environment... relies on it); nothing is compiled here."""
    import dataclasses

    from mjx_push.train.loop import make_train

    if len(jax.devices()) < 2:
        pytest.skip("one device: MJX_PUSH_CPU_DEVICES=1 or a one-core machine, nothing to split")
    cfg = tiny_run_config("vpm", None)  # 4 environments: two cuboids, two cylinders
    adapter = make_push_adapter(cfg.env, None)
    wrapped = dataclasses.replace(adapter, step=lambda s, a: adapter.step(s, a))
    assert make_train(cfg.train, adapter).rollout_split == "groups"
    assert make_train(cfg.train, wrapped).rollout_split == "physics"
    cylinders = dataclasses.replace(cfg.env, objects=dataclasses.replace(cfg.env.objects, shape="cylinder"))
    want = "episodes" if devices.shard_map_compiles() else "physics"  # one group: each device a share of it
    assert make_train(cfg.train, make_push_adapter(cylinders, None)).rollout_split == want
    assert make_train(cfg.train, make_push_adapter(cfg.env, None, max_devices=1)).rollout_split is None

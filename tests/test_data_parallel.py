"""Data-parallel training (train/data_parallel.py): the averaged update, the per-device layout of a
run, its errors, and one run over two processes on localhost (jax.distributed with CPU collectives)."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import Mesh, PartitionSpec as P

from mjx_push.errors import ConfigError
from tests.test_learner_sac import KEY
from tests import two_processes
from tests.toy import TAU, make_toy, toy_config
from mjx_push.train import data_parallel
from mjx_push.train.config import LoopConfig
from mjx_push.train.loop import Runner, make_train
from mjx_push.train.networks import make_networks
from mjx_push.train.sac import make_update

two_devices = pytest.mark.skipif(len(jax.devices()) < 2, reason="needs 2 CPU host devices (a machine with 2 cores)")


@two_devices
def test_the_update_over_two_devices_averages_the_devices_gradients(real_update):
    """Each device takes its half of the batch and both apply the averaged step: identical parameters on
    both, the single-device step when both halves are the same, and neither half's own step when they
    differ (a device stepping on its own half alone would end there)."""
    agent, cfg, state, batch = real_update
    nets = make_networks(agent)
    half = lambda b, i: jax.tree.map(lambda x: x[4 * i : 4 * i + 4], b)  # noqa: E731
    single = jax.jit(make_update(agent, cfg, nets=nets))
    mesh = Mesh(np.array(jax.devices()[:2]), (data_parallel.AXIS,))
    update = make_update(agent, cfg, nets=nets, axis_name=data_parallel.AXIS)
    # Each device's whole resulting state (actor, critics, targets, temperature, every optimiser
    # state, the step), stacked over a leading device axis.
    sharded = jax.jit(
        jax.shard_map(
            lambda s, b: jax.tree.map(lambda x: x[None], update(s, b, KEY)[0]),
            mesh=mesh,
            in_specs=(P(), P(data_parallel.AXIS)),
            out_specs=P(data_parallel.AXIS),
            check_vma=False,
        )
    )
    # The results are read on the host (jax.device_get copies each shard; no program runs), never
    # indexed on the devices: each eager index of an array spread over both devices is a small
    # two-device program, and a burst of them dispatched while the update still ran stalled one
    # device's side of a collective until XLA aborted the process (its 40 s rendezvous timeout; about
    # one run in eight on 2 cores, and once in CI).
    both = jax.device_get(sharded(state, batch))
    _assert_same_on_every_device(both, lambda x: [x[0], x[1]])
    same = jax.device_get(sharded(state, jax.tree.map(lambda x: jnp.concatenate([x, x]), half(batch, 0))))
    alone = [single(state, half(batch, i), KEY)[0] for i in range(2)]
    for (path, a), b in zip(
        jax.tree_util.tree_leaves_with_path(jax.tree.map(lambda x: x[0], same)), jax.tree.leaves(alone[0])
    ):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7, err_msg=jax.tree_util.keystr(path))
    averaged = jax.tree.map(lambda x: x[0], both)
    for part in ("actor_params", "critic_params"):  # each is averaged, not a device's own step
        for own in alone:
            moved = [
                np.abs(np.ravel(a) - np.ravel(o)).max()
                for a, o in zip(jax.tree.leaves(getattr(averaged, part)), jax.tree.leaves(getattr(own, part)))
            ]
            assert max(moved) > 1e-6, part


def _assert_same_on_every_device(tree, per_device) -> None:
    """Every leaf of ``tree`` holds the same value on every device (``per_device(leaf)`` lists them),
    naming the first leaf that differs."""
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        first, *rest = [np.asarray(v) for v in per_device(leaf)]
        for other in rest:
            np.testing.assert_array_equal(first, other, err_msg=f"differs across devices: {jax.tree_util.keystr(path)}")


def test_without_a_coordinator_the_run_is_one_process(monkeypatch):
    for name in ("MJX_PUSH_COORDINATOR", "MJX_PUSH_NUM_PROCESSES", "MJX_PUSH_PROCESS_ID"):
        monkeypatch.delenv(name, raising=False)
    data_parallel.initialize()
    assert jax.process_count() == 1 and data_parallel.is_primary()


def test_a_data_parallel_run_checks_its_shapes_and_devices():
    with pytest.raises(ConfigError, match="loop.num_envs.*multiple of loop.data_parallel"):
        LoopConfig(num_envs=6, data_parallel=4)
    with pytest.raises(ConfigError, match="sac.batch_size must be a multiple of loop.data_parallel"):
        make_train(
            dataclasses.replace(toy_config("vpm", 800, batch_size=127), loop=LoopConfig(num_envs=8, data_parallel=2)),
            make_toy(success_tau=TAU),
        )
    with pytest.raises(ConfigError, match="process id 2 is not one of 2 processes"):
        data_parallel.initialize("localhost:1", 2, 2)
    with pytest.raises(ConfigError, match="--coordinator auto takes the process count"):
        data_parallel.initialize("auto", 2, 0)
    many = toy_config("vpm", 800, data_parallel=8)
    with pytest.raises(ConfigError, match=f"loop.data_parallel is 8 but this run has {len(jax.devices())} device"):
        Runner(make_train(many, make_toy(success_tau=TAU)))


@two_devices
def test_each_device_holds_its_share_and_the_expert_demonstrates_on_every_device():
    cfg = dataclasses.replace(
        toy_config("vpm", 800, data_parallel=2), demo=dataclasses.replace(toy_config("vpm", 800).demo, fraction=0.25)
    )
    runner = Runner(make_train(cfg, make_toy(success_tau=TAU)))
    ts = runner.init(jax.random.PRNGKey(0))
    buffer = jax.tree.leaves(ts.buffer.data)[0]
    assert buffer.shape[0] == 2 and buffer.sharding.spec == P(data_parallel.AXIS)
    assert buffer.shape[1] == 20_000 // 10 // 2  # half of the capacity's episodes on each device
    mask = runner.expert_envs(10_000)  # after the warm-up: 2 of 8 environments, one per device
    assert mask.sum() == 2 and mask[:4].sum() == 1 and mask[4:].sum() == 1
    eps, stats = runner.rollout(ts.sac.actor_params, jax.random.PRNGKey(1), jnp.asarray(False), jnp.asarray(True), mask)
    assert eps["valid"].shape[0] == 8 and eps["valid"].sharding.spec == P(data_parallel.AXIS)
    assert isinstance(stats["episode_success"], np.ndarray) and stats["episode_success"].shape == (8,)
    # The two devices' environments are different episodes (each device has a key of its own).
    goals = np.asarray(eps["goal_xy"])
    assert not np.allclose(goals[:4], goals[4:])


@two_devices
def test_every_replicated_field_of_the_learner_stays_equal_on_both_devices():
    """After batches with updates, every field of the state but the replay shards (actor, critics,
    targets, temperature, optimiser states, input statistics, keys, counters, best actor) holds the
    same value on both devices: each device's copy is read on its own, so a missing average of any
    gradient or of the statistics' episodes shows here."""
    base = toy_config("vpm", 640, data_parallel=2)
    cfg = dataclasses.replace(base, agent=dataclasses.replace(base.agent, obs_norm=True))
    runner = Runner(make_train(cfg, make_toy(success_tau=TAU)))
    ts, learned = runner.init(jax.random.PRNGKey(0)), 0
    while int(ts.env_steps) < cfg.loop.total_env_steps:
        ts, metrics = runner.iteration(ts)
        learned += bool(metrics["learning"])
    assert learned >= 2 and ts.norm_stats  # updates ran, and there are statistics to compare
    _assert_same_on_every_device(
        ts.replace(buffer=None),
        lambda x: [shard.data for shard in sorted(x.addressable_shards, key=lambda s: s.device.id)],
    )


def test_two_processes_train_one_run_and_resume_it(tmp_path):
    """Two processes on localhost, one CPU device each, train the toy task as one run: stopped after 6
    batches (as if killed), resumed from the checkpoint of batch 4, finished at 8, with updates on
    both sides of the stop. Both end with the same learner state, only process 0 wrote the logs and
    policies. (That such a run learns the task as well as one device is `toy-two-processes` in
    benchmarks/learning_checks.py.)"""
    train = toy_config("vpm", 640, data_parallel=2, warmup_env_steps=160, eval_every_env_steps=320)
    config = two_processes.write_config(tmp_path / "config-in.json", two_processes.toy_run(train))
    run_dir = tmp_path / "run"
    two_processes.launch(run_dir, config, "--stop-after", "6", timeout=400)
    assert all(s["stopped_at_env_steps"] == 6 * 80 for s in two_processes.summaries(run_dir))
    assert sorted(p.name for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit()) == ["320"]
    two_processes.launch(run_dir, config, "--resume", timeout=400)
    a, b = (np.load(run_dir / f"state-{i}.npz") for i in range(2))
    assert len(a.files) > 20 and a.files == b.files  # the whole learner state, not the actor alone
    for k in a.files:
        np.testing.assert_array_equal(a[k], b[k], err_msg=f"differs across processes: {k}")
    summaries = two_processes.summaries(run_dir)
    assert all(s["devices"] == 2 and s["processes"] == 2 for s in summaries)
    main = summaries[0]
    assert main["resumed_from_env_steps"] == 320 and main["env_steps"] == 640
    assert summaries[1]["best_eval_success_rate"] == main["best_eval_success_rate"]
    assert (run_dir / "best_policy.msgpack").is_file() and (run_dir / "summary.json").is_file()
    rows = (run_dir / "metrics.csv").read_text().splitlines()
    assert len(rows) == 1 + 8  # one header, one row per batch, written once

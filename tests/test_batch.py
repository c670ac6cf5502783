"""The mixed-shape batch: shape groups, determinism, utilisation, bad input."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import objects
from mjx_push import batch as batch_module
from mjx_push.batch import BatchState, PushBatch
from mjx_push.env import EnvConfig, decode_substeps
from tests.helpers import a_s_for


@pytest.fixture(scope="module")
def batch():
    return PushBatch(EnvConfig(), 4)


def rollout(batch, seed, n=3):
    key = jax.random.PRNGKey(seed)
    state = batch.jit_reset(key)
    out = [state]
    for i in range(n):
        a = jax.random.uniform(jax.random.fold_in(key, i), (4, 3), minval=-1, maxval=1)
        a = a.at[:, 2].set(-0.95)  # short steps keep the test fast
        state = batch.jit_step(state, a)
        out.append(state)
    return out


def test_groups_and_concatenation(batch):
    assert batch.geom_types == ("box", "cylinder") and batch.counts == (2, 2)
    states = rollout(batch, 0, 1)
    s = states[-1]
    assert s.obs["object_mask"].shape == (4, 64, 64) and s.obs["ee_xy"].shape == (4, 2)
    assert s.reward.shape == (4,) and s.info["goal_xy"].shape == (4, 2)
    # Box group first: its geom sizes have three non-zero half extents, cylinders a zero third entry.
    size = np.asarray(s.info["params"].size)
    assert np.all(size[:2, 2] > 0) and np.all(size[2:, 2] == 0)
    np.testing.assert_array_equal(np.asarray(s.info["step"]), [1, 1, 1, 1])
    # Observation: the noisy flange xy is within a few noise std of the truth.
    assert np.all(np.abs(np.asarray(s.obs["ee_xy"] - s.info["ee_xy_true"])) < 1e-3)


def test_eager_joins_of_the_groups_each_wait_before_the_next(monkeypatch):
    """Read outside a trace, each leaf's join of the groups waits for its inputs and its result before
    the next leaf is joined (a burst of joins over the host devices can deadlock on CPU:
    benchmarks/collective_burst.py); traced, none waits."""
    events = []
    concatenate, wait = jnp.concatenate, jax.block_until_ready
    monkeypatch.setattr(
        batch_module.jnp, "concatenate", lambda xs, axis: events.append("join") or concatenate(xs, axis)
    )
    monkeypatch.setattr(batch_module.jax, "block_until_ready", lambda x: events.append("wait") or wait(x))
    groups = ({"a": jnp.ones((2, 3)), "b": jnp.zeros(2)}, {"a": jnp.zeros((1, 3)), "b": jnp.ones(1)})
    joined = BatchState(groups=groups).cat(lambda g: g)
    assert events == ["wait", "join", "wait"] * 2
    np.testing.assert_array_equal(joined["b"], [0, 0, 1])
    events.clear()
    jax.jit(lambda s: s.cat(lambda g: g))(BatchState(groups=groups))
    assert events == ["join", "join"]


def test_same_key_same_trajectory_bitwise(batch):
    a, b = rollout(batch, 3), rollout(batch, 3)
    for sa, sb in zip(a, b):
        for x, y in zip(jax.tree.leaves(sa), jax.tree.leaves(sb)):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    c = rollout(batch, 4, 1)
    assert not np.array_equal(np.asarray(c[0].info["goal_xy"]), np.asarray(a[0].info["goal_xy"]))


def test_step_phases_in_chunks_give_the_steps_result(batch):
    """A scheduler's view (begin, advance in chunks of 7 substeps, finish each environment when its own
    substeps are spent) reproduces `step`, where every environment waits for the slowest."""
    state = batch.jit_reset(jax.random.PRNGKey(5))
    lo, hi = batch.config.substeps
    n = np.array([lo, lo + 9, lo + 20, lo + 3])  # different step lengths: the environments drift apart
    a_s = jnp.asarray([a_s_for(int(k), lo, hi) for k in n])
    a = jnp.concatenate([jax.random.uniform(jax.random.PRNGKey(6), (4, 2), minval=-1, maxval=1), a_s[:, None]], 1)
    want = batch.jit_step(state, a)
    begin, advance, ready, finish = (
        jax.jit(batch.begin),
        jax.jit(batch.advance, static_argnums=1),
        jax.jit(batch.ready),
        jax.jit(batch.finish),
    )
    s = begin(state, a, jnp.ones(4, bool))
    finished = np.zeros(4, bool)
    while not finished.all():
        s = advance(s, 7)
        done = np.asarray(ready(s)) & ~finished
        s = finish(s, jnp.asarray(done))
        finished |= done
    np.testing.assert_array_equal(np.asarray(s.info["substeps"]), n)
    for get in (
        lambda x: x.obs["ee_xy"],
        lambda x: x.obs["object_mask"],
        lambda x: x.info["object_xy"],
        lambda x: x.info["ee_xy_true"],
        lambda x: x.info["step"],
        lambda x: x.reward,
        lambda x: x.info["corrections"].distance,
    ):
        np.testing.assert_allclose(np.asarray(get(s), np.float64), np.asarray(get(want), np.float64), atol=1e-6)


def _eqns(jaxpr):
    """Every equation of a jaxpr, sub-jaxprs (loops, conds, shard_map, pjit) included."""
    for e in jaxpr.eqns:
        yield e
        for v in e.params.values():
            for sub in v if isinstance(v, (tuple, list)) else (v,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    yield from _eqns(inner)


def test_a_chunk_of_substeps_has_a_trip_count_known_at_compile_time(batch):
    """The scheduler's chunk is a loop of exactly `max_substeps` iterations (a scan: XLA compiles it
    to a while loop with a known trip count), not a loop whose predicate the device must evaluate and
    send to the host after every substep."""
    # Shapes only (traced, never run: an eager `begin` dispatches op by op and took minutes).
    state = jax.eval_shape(
        lambda k: batch.begin(batch.reset(k), jnp.zeros((4, 3)), jnp.ones(4, bool)), jax.random.PRNGKey(1)
    )
    eqns = list(_eqns(jax.make_jaxpr(lambda s: batch.advance(s, 7))(state).jaxpr))
    chunks = [e for e in eqns if e.primitive.name == "scan" and e.params["length"] == 7]
    assert len(chunks) == len(batch.envs)  # one per shape group


def test_utilisation(batch):
    n = jnp.array([10, 600, 300, 300])
    # Box group waits for 600 (useful 610 of 1200), cylinder group for 300 (600 of 600).
    assert float(batch.utilisation(n)) == pytest.approx(1210 / 1800)
    assert float(batch.utilisation(jnp.array([300, 300, 300, 300]))) == 1.0


def test_decode_substeps_range():
    a = jnp.array([-1.0, 0.0, 1.0, 2.0, -3.0])
    np.testing.assert_array_equal(np.asarray(decode_substeps(a, (10, 600))), [10, 305, 600, 600, 10])
    np.testing.assert_array_equal(np.asarray(decode_substeps(a, (10, 150))), [10, 80, 150, 150, 10])


def test_bad_input(batch):
    state = batch.jit_reset(jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match=r"actions must have shape \(4, 3\)"):
        batch.step(state, jnp.zeros((3, 3)))
    with pytest.raises(ValueError, match="num_envs >= 2"):
        PushBatch(EnvConfig(), 1)
    with pytest.raises(ValueError, match="num_envs must be a positive integer"):
        PushBatch(EnvConfig(), 0)
    with pytest.raises(ValueError, match="env.substeps"):
        EnvConfig(substeps=(0, 600))
    with pytest.raises(ValueError, match="env.workspace_x"):
        EnvConfig(workspace_x=(0.6, 0.1))
    with pytest.raises(ValueError, match="objects.shape"):
        EnvConfig(objects=objects.ObjectConfig(shape="sphere"))
    single = PushBatch(EnvConfig(objects=objects.ObjectConfig(shape="cylinder")), 1)
    assert single.geom_types == ("cylinder",) and single.counts == (1,)
    group = PushBatch(EnvConfig(), 1, shapes=("cylinder",))  # one group of a mixed batch, on its own
    assert group.geom_types == ("cylinder",) and group.counts == (1,)
    for bad, cfg in (
        (("box", "cylinder"), EnvConfig(objects=objects.ObjectConfig(shape="cylinder"))),
        (("cylinder", "box"), EnvConfig()),
        ((), EnvConfig()),
    ):
        with pytest.raises(
            ValueError, match=r"shapes must be some of the shape filter .*, got " + re.escape(repr(bad))
        ):
            PushBatch(cfg, 4, shapes=bad)


def test_the_batch_is_split_over_the_host_devices_and_steps_as_on_one(batch):
    """mjx_push.xla asks for one CPU device per core (2 here, or MJX_PUSH_CPU_DEVICES); each shape group
    is split evenly over them, and every environment's trajectory is the one a single device gives."""
    if len(jax.devices()) < 2:
        pytest.skip("one device: MJX_PUSH_CPU_DEVICES=1 or a one-core machine, nothing to split")
    assert batch.num_devices == 2 and batch.mesh.size == 2
    one = PushBatch(EnvConfig(), 4, max_devices=1)
    assert one.mesh is None and one.num_devices == 1
    split, single = rollout(batch, 6, 2), rollout(one, 6, 2)
    for s in (split[-1].groups[0], split[-1].groups[1]):
        assert len(s.pipeline_state.qpos.sharding.device_set) == 2  # each group lives on both devices
    # The same physics, up to float rounding (XLA fuses a batch of 1 and of 2 differently).
    a, b = split[-1], single[-1]
    np.testing.assert_allclose(
        np.asarray(a.cat(lambda s: s.pipeline_state.qpos)),
        np.asarray(b.cat(lambda s: s.pipeline_state.qpos)),
        atol=1e-5,
    )
    for key in ("object_xy", "ee_xy_true", "substeps", "step"):
        np.testing.assert_allclose(np.asarray(a.info[key]), np.asarray(b.info[key]), atol=1e-5)
    np.testing.assert_array_equal(np.asarray(a.reward), np.asarray(b.reward))
    assert np.mean(np.asarray(a.obs["object_mask"]) != np.asarray(b.obs["object_mask"])) < 0.005
    moved = np.abs(np.asarray(split[-1].info["ee_xy_true"] - split[0].info["ee_xy_true"]))
    assert moved.max() > 1e-4  # the arms moved: the comparison is of a real step


def test_device_mesh_splits_every_group_evenly():
    from mjx_push.devices import env_mesh

    n = len(jax.devices())
    mesh = env_mesh((16, 16))
    assert (mesh is None) == (n == 1) and (mesh is None or 16 % mesh.size == 0)
    assert env_mesh((16, 16), max_devices=1) is None
    assert env_mesh((3, 5)) is None  # no common divisor above 1: one device
    if n >= 2:
        assert env_mesh((2, 4)).size == 2 and env_mesh((7,)) is None

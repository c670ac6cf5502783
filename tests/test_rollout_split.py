"""A batch's rollout split over host devices by whole episodes gives the episodes of the same batch on
one device, in the batch's order: one program per group on devices of its own (`make_group_collect`)
and each device running its share of every group (`make_split_collect`). Checked on a toy of two groups
that move their object at different speeds (a group run by the wrong program, or episodes returned in
the wrong order, change the episodes), with a recurrent actor, the expert in some environments and
random warm-up actions; it compiles in seconds. The pushing scene's groups: tests/test_tiny_egru_run.py."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import devices
from mjx_push.errors import ConfigError
from mjx_push.train.adapter import EnvAdapter
from mjx_push.train.loop import Runner, make_train
from mjx_push.train.rollout import make_collect, make_group_collect, make_split_collect
from tests.toy import latent_map, toy_config

SPEEDS = (0.05, 0.02)  # each group's object moves this far per unit action


def two_group_toy(group: int | None = None, max_devices: int | None = None) -> EnvAdapter:
    """The toy task laid out like the pushing scene's batch: the first ceil(N/2) environments group 0,
    the rest group 1 (only ``group``'s when given); ``reset`` takes a batch key or the environments'
    own keys [N, 2]."""
    M, held = latent_map(0, 0.15), (0, 1) if group is None else (group,)

    def counts(n: int) -> tuple[int, ...]:
        return (n - n // 2, n // 2) if len(held) == 2 else (n,)

    def observe(xy):
        return {"ee_xy": xy, "z_obj": xy @ M, "obj_xy": xy, "priv": xy}

    def reset(key, n):
        keys = key if jnp.ndim(key) == 2 else jax.random.split(key, n)
        obj, goal = (jax.vmap(lambda k, i=i: jax.random.uniform(jax.random.fold_in(k, i), (2,), minval=-0.15, maxval=0.15))(keys) for i in (0, 1))  # fmt: skip
        speed = jnp.concatenate([jnp.full(c, SPEEDS[g]) for g, c in zip(held, counts(n))])
        return {"xy": obj, "speed": speed}, observe(obj), {"z_goal": goal @ M, "goal_xy": goal}

    def step(state, action):
        xy = jnp.clip(state["xy"] + state["speed"][:, None] * action[:, :2], -0.15, 0.15)
        return {**state, "xy": xy}, observe(xy), jnp.zeros(xy.shape[:1], bool)

    def expert(step_obs, info):
        a = jnp.clip((info["goal_xy"] - step_obs["priv"]) / SPEEDS[0], -1.0, 1.0)
        return jnp.concatenate([a, jnp.ones_like(a[:, :1])], axis=1)

    one_device = None
    if max_devices != 1:
        one_device = lambda adapter, g=None: two_group_toy(g, max_devices=1)  # noqa: E731
    return EnvAdapter(
        reset=reset,
        step=step,
        success_tau=0.025,
        episode_len=5,
        priv_dim=2,
        expert=expert,
        mesh=(lambda n: devices.env_mesh(counts(n), max_devices)),
        one_device=one_device,
        groups=counts,
    )


@pytest.fixture(scope="module")
def two_devices():
    if len(jax.devices()) < 2:
        pytest.skip("one device: MJX_PUSH_CPU_DEVICES=1 or a one-core machine, nothing to split")


@pytest.mark.parametrize("random_actions", [False, True])
def test_whole_episode_splits_give_one_devices_episodes(two_devices, random_actions):
    cfg = toy_config("ugru", 80, num_envs=8, warmup_env_steps=40, eval_episodes=8, hidden=(16, 16))
    adapter = two_group_toy()
    trainer = make_train(cfg, adapter)
    # One device per group on 2 cores; more cores give each group's program a share of them.
    assert trainer.rollout_split == "groups" and trainer.rollout_mesh.size % 2 == 0
    params = trainer.init(jax.random.PRNGKey(0)).sac.actor_params
    expert = jnp.asarray([True, False, False, False, False, True, False, False])  # in both groups
    flags = (jnp.asarray(random_actions), jnp.asarray(False), expert)
    on_one = make_collect(cfg, two_group_toy(max_devices=1), trainer.networks)
    want, want_stats = jax.jit(lambda p, k: on_one(p, k, 8, *flags))(params, jax.random.PRNGKey(3))
    grouped = Runner(trainer).rollout(params, jax.random.PRNGKey(3), *flags)
    shares = make_split_collect(cfg, adapter.one_device(adapter), trainer.networks, trainer.rollout_mesh, (4, 4))
    split = jax.jit(lambda p, k: shares(p, k, 8, *flags))(params, jax.random.PRNGKey(3))
    for got, got_stats in (grouped, split):
        assert got.keys() == want.keys() and got_stats.keys() == want_stats.keys()
        for k in want:
            np.testing.assert_allclose(np.asarray(got[k]), np.asarray(want[k]), rtol=1e-5, atol=1e-6, err_msg=k)
        for k in want_stats:
            np.testing.assert_allclose(np.asarray(got_stats[k]), np.asarray(want_stats[k]), rtol=1e-5, err_msg=k)
    assert grouped[0]["obj_xy"].sharding.device_set == {jax.devices()[0]}  # on the learner's device
    moved = np.abs(np.diff(np.asarray(want["obj_xy"]), axis=1)).max(axis=(1, 2))
    assert (moved[4:] <= SPEEDS[1] + 1e-6).all() and (moved[:4] > SPEEDS[1] + 1e-6).any()  # the groups differ


def test_a_group_program_needs_devices_of_its_own(two_devices):
    cfg = toy_config("vpm", 80, num_envs=6, hidden=(16, 16))
    adapter = two_group_toy()
    nets = make_train(cfg, two_group_toy(max_devices=1)).networks
    twins = [adapter.one_device(adapter, g) for g in range(2)]
    one = jax.sharding.Mesh(np.asarray(jax.devices()[:1]), (devices.AXIS,))
    with pytest.raises(ConfigError, match=r"2 groups over 1 devices: each group needs devices of its own"):
        make_group_collect(cfg, twins, nets, one, (3, 3))
    collect = make_group_collect(cfg, twins, nets, devices.env_mesh((2,)), (3, 3))
    with pytest.raises(ConfigError, match=r"laid out for 6 environments, got 8"):
        collect(None, jax.random.PRNGKey(0), 8, False, False, False)
    with pytest.raises(ConfigError, match=r"runs its compiled programs itself: call it unjitted"):
        jax.jit(lambda k: collect(None, k, 6, False, False, False))(jax.random.PRNGKey(0))

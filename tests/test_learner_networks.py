"""Feature extractors, actor and twin critic (train/networks.py)."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push.train import replay
from mjx_push.train.config import AgentConfig, ReplayConfig
from mjx_push.train.networks import make_networks, squash

KINDS = ["vpm", "stacked", "ugru"]
B, T = 3, 7


def random_episode(key, batch=B, length=T + 1):
    k1, k2, k3 = jax.random.split(key, 3)
    return {
        "ee_xy": jax.random.normal(k1, (batch, length, 2)),
        "z_obj": jax.random.normal(k2, (batch, length, 6)),
        "z_goal": jax.random.normal(k3, (batch, 6)),
    }


def all_features(nets, actor_params, ep):
    return nets.actor.apply(actor_params, ep["ee_xy"], ep["z_obj"], ep["z_goal"], method=lambda m, *a: m.features(*a))


def steps(batch, length):
    return jnp.tile(jnp.arange(length)[None], (batch, 1))


@pytest.fixture(scope="module", params=KINDS)
def agent(request):
    nets = make_networks(AgentConfig(request.param))
    actor, critic = nets.init(jax.random.PRNGKey(0), T)
    return nets, actor, critic


def test_vpm_features_are_the_current_14_vector():
    nets = make_networks(AgentConfig("vpm"))
    actor, _ = nets.init(jax.random.PRNGKey(0), T)
    ep = random_episode(jax.random.PRNGKey(1))
    f = np.asarray(all_features(nets, actor, ep))
    t = 4
    expected = np.concatenate([ep["ee_xy"][:, t], ep["z_obj"][:, t], ep["z_goal"]], axis=-1)
    np.testing.assert_array_equal(f[:, t], expected)


def test_stacked_features_are_last_five_zero_padded():
    nets = make_networks(AgentConfig("stacked"))
    actor, _ = nets.init(jax.random.PRNGKey(0), T)
    ep = random_episode(jax.random.PRNGKey(1))
    f = np.asarray(all_features(nets, actor, ep))
    flat = np.concatenate([ep["ee_xy"], ep["z_obj"], np.broadcast_to(ep["z_goal"][:, None], (B, T + 1, 6))], -1)
    padded = np.concatenate([np.zeros((B, 4, 14)), flat], axis=1)
    for t in range(T + 1):
        np.testing.assert_allclose(f[:, t], padded[:, t : t + 5].reshape(B, 70), atol=0)
    assert np.all(f[:, 0, :56] == 0) and np.any(f[:, 0, 56:] != 0)  # step 0: four zero frames, then o_0


def test_features_are_causal(agent):
    """Garbage after step t must not change the features (hence the actions) at steps <= t."""
    nets, actor, critic = agent
    ep = random_episode(jax.random.PRNGKey(1))
    t = 3
    garbage = jax.tree.map(lambda x: x, ep)
    for name in ("ee_xy", "z_obj"):
        junk = 1e3 * jax.random.normal(jax.random.PRNGKey(9), ep[name][:, t + 1 :].shape)
        garbage[name] = ep[name].at[:, t + 1 :].set(junk)
    f_ok, f_bad = all_features(nets, actor, ep), all_features(nets, actor, garbage)
    np.testing.assert_array_equal(np.asarray(f_ok[:, : t + 1]), np.asarray(f_bad[:, : t + 1]))
    assert not np.allclose(f_ok[:, t + 1 :], f_bad[:, t + 1 :])  # the garbage did reach later steps
    idx = steps(B, t + 1)
    a = jnp.zeros((B, t + 1, 3))
    np.testing.assert_array_equal(np.asarray(nets.q(critic, ep, idx, a)), np.asarray(nets.q(critic, garbage, idx, a)))


def test_online_act_matches_whole_episode(agent):
    """Step-by-step acting with a carry gives the whole-episode policy's actions (same noise)."""
    nets, actor, _ = agent
    ep = random_episode(jax.random.PRNGKey(2))
    keys = jax.random.split(jax.random.PRNGKey(3), T + 1)

    @jax.jit
    def online(deterministic):
        def body(carry, x):
            obs, key = x
            action, carry = nets.act(actor, carry, {**obs, "z_goal": ep["z_goal"]}, key, deterministic)
            return carry, action

        seq = {k: jnp.swapaxes(ep[k], 0, 1) for k in ("ee_xy", "z_obj")}
        return jnp.swapaxes(jax.lax.scan(body, nets.init_carry(B), (seq, keys))[1], 0, 1)

    noise = jnp.swapaxes(jax.vmap(lambda k: jax.random.normal(k, (B, 3)))(keys), 0, 1)
    idx = steps(B, T + 1)
    for deterministic, n in ((True, jnp.zeros_like(noise)), (False, noise)):
        whole, _ = nets.policy(actor, ep, idx, n)
        np.testing.assert_allclose(np.asarray(online(deterministic)), np.asarray(whole), rtol=0, atol=1e-6)
    assert not np.allclose(online(True), online(False))  # the noise really is used when stochastic


def test_gru_features_with_relabelled_goal_equal_a_fresh_scan():
    """After HER relabelling, every hidden state is recomputed with the new goal: the batched features
    equal a fresh step-by-step nn.GRUCell scan over [z_obj_t, new z_goal, ee_xy_t]."""
    T_ = 6
    nets = make_networks(AgentConfig("ugru"))
    actor, _ = nets.init(jax.random.PRNGKey(0), T_)
    buf = replay.init(ReplayConfig(capacity_transitions=4 * T_, her_k=4), T_, success_tau=0.01)
    k = jax.random.split(jax.random.PRNGKey(5), 4)
    episodes = {
        "z_obj": jax.random.normal(k[0], (4, T_ + 1, 6)),
        "ee_xy": jax.random.normal(k[1], (4, T_ + 1, 2)),
        "obj_xy": jax.random.normal(k[2], (4, T_ + 1, 2)),
        "z_goal": jax.random.normal(k[3], (4, 6)),
        "goal_xy": jnp.zeros((4, 2)),
        "action": jnp.zeros((4, T_, 3)),
        "valid": jnp.ones((4,), bool),
    }
    buf = replay.add(buf, episodes)
    batch = replay.sample(buf, jax.random.PRNGKey(6), 16)
    assert bool(jnp.any(batch["relabelled"]))

    feats = all_features(nets, actor, batch)  # [16, T+1, 32], with the batch's (relabelled) goal
    cell_params = {"params": actor["params"]["features"]["cell"]}
    h = jnp.zeros((16, 32))
    for t in range(T_ + 1):
        x = jnp.concatenate([batch["z_obj"][:, t], batch["z_goal"], batch["ee_xy"][:, t]], -1)
        h, _ = nn.GRUCell(32).apply(cell_params, h, x)
        np.testing.assert_allclose(np.asarray(feats[:, t]), np.asarray(h), atol=1e-5)

    # ...and they differ from the features computed with the stored goal wherever it was replaced.
    stored = {**batch, "z_goal": episodes["z_goal"][batch["episode"]]}
    old = all_features(nets, actor, stored)
    r = np.asarray(batch["relabelled"])
    assert np.all(np.abs(np.asarray(old - feats)[r]).max(axis=(1, 2)) > 1e-4)
    np.testing.assert_array_equal(np.asarray(old)[~r], np.asarray(feats)[~r])


def test_squash_log_prob_matches_change_of_variables():
    mean = jnp.array([[0.3, -1.0, 8.0]])
    log_std = jnp.array([[-0.5, 0.2, 1.0]])
    noise = jnp.array([[0.7, -1.3, 2.5]])  # the last one saturates tanh (u = 14.8)
    a, logp = squash(mean, log_std, noise)
    u = np.float64(mean) + np.exp(np.float64(log_std)) * np.float64(noise)
    std = np.exp(np.float64(log_std))
    gauss = -0.5 * ((u - np.float64(mean)) / std) ** 2 - np.log(std) - 0.5 * np.log(2 * np.pi)
    # log(1 - tanh(u)^2) = log(sech(u)^2) = -2 log cosh(u), exact in float64 even where tanh(u) == 1.
    log_jac = -2.0 * (np.abs(u) + np.log1p(np.exp(-2 * np.abs(u))) - np.log(2.0))
    np.testing.assert_allclose(np.asarray(a), np.tanh(u), rtol=1e-6)
    np.testing.assert_allclose(float(logp[0]), np.sum(gauss - log_jac), rtol=1e-5)
    assert np.isfinite(float(logp[0]))


def test_squashed_density_integrates_to_one():
    """The tanh correction's sign and size: the 1-D density of a = tanh(u) integrates to 1 on (-1, 1)."""
    mean, log_std = jnp.float32(0.4), jnp.float32(-0.3)
    u = jnp.linspace(-6.0, 6.0, 20001)
    noise = ((u - mean) / jnp.exp(log_std))[:, None]
    a, logp = squash(jnp.full((u.size, 1), mean), jnp.full((u.size, 1), log_std), noise)
    a, p = np.asarray(a[:, 0], np.float64), np.exp(np.asarray(logp, np.float64))
    assert abs(np.trapezoid(p, a) - 1.0) < 1e-3


def test_log_std_is_clipped():
    nets = make_networks(AgentConfig("vpm"))
    actor, _ = nets.init(jax.random.PRNGKey(0), T)
    ep = random_episode(jax.random.PRNGKey(1))
    idx = steps(B, 2)
    for bias, bound in ((100.0, 2.0), (-100.0, -20.0)):
        p = jax.tree.map(lambda x: x, actor)
        p["params"]["log_std_head"]["bias"] = jnp.full((3,), bias)
        _, log_std = nets.actor.apply(p, ep["ee_xy"], ep["z_obj"], ep["z_goal"], idx)
        np.testing.assert_array_equal(np.asarray(log_std), bound)


def test_twin_critics_and_actor_share_no_weights(agent):
    nets, actor, critic = agent
    # Each critic leaf carries a leading axis of 2 (two independent networks, extractor included).
    assert all(x.shape[0] == 2 for x in jax.tree.leaves(critic))
    if nets.agent.kind == "ugru":
        assert "features" in critic["params"] and "features" in actor["params"]
    ep = random_episode(jax.random.PRNGKey(1))
    idx, a = steps(B, 2), jnp.zeros((B, 2, 3))
    q = nets.q(critic, ep, idx, a)
    assert q.shape == (2, B, 2) and not np.allclose(q[0], q[1])
    # The first critic's output depends on none of the second critic's parameters.
    g = jax.grad(lambda c: nets.q(c, ep, idx, a)[0].sum())(critic)
    assert all(float(jnp.abs(x[1]).max()) == 0.0 for x in jax.tree.leaves(g))
    assert any(float(jnp.abs(x[0]).max()) > 0.0 for x in jax.tree.leaves(g))

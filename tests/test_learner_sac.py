"""SAC losses and update (train/sac.py) against hand-computed values.

A stub "network" makes every number computable by hand:
  policy:  a = a_param + 0.1 * idx (per action dim), log pi = lp_param (noise ignored)
  critics: Q_i = w_i * sum(a) + c_i * idx
The worked numbers are in the comments next to each expectation.
"""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push.train.config import AgentConfig, SACConfig
from mjx_push.train.networks import make_networks
from mjx_push.train.sac import (
    SACState,
    actor_loss_value,
    alpha_loss,
    critic_loss_value,
    init_state,
    make_actor_loss,
    make_critic_loss,
    make_optimizer,
    make_update,
    td_target,
)


class StubNets:
    action_dim = 3

    def policy(self, p, episode, idx, noise):
        a = p["a"] + 0.1 * idx[..., None].astype(jnp.float32)
        return a, jnp.broadcast_to(p["lp"], idx.shape)

    def deterministic_action(self, p, episode, idx):
        return self.policy(p, episode, idx, None)[0]

    def policy_with_mode(self, p, episode, idx, noise):
        return (*self.policy(p, episode, idx, noise), self.deterministic_action(p, episode, idx))

    def actor_features(self, p, episode):
        steps = jnp.arange(8, dtype=jnp.float32)[None, :, None]  # the action's per-step part, as a feature
        return jnp.broadcast_to(p["a"] + 0.1 * steps, (episode["t"].shape[0], 8, 3))

    def policy_from_features(self, p, features, idx, noise):
        a = jnp.take_along_axis(features, idx[..., None], axis=1)
        return a, jnp.broadcast_to(p["lp"], idx.shape), a

    def q(self, p, episode, idx, action):
        return p["w"][:, None, None] * jnp.sum(action, -1)[None] + p["c"][:, None, None] * idx[None]


ACTOR = {"a": jnp.full((3,), 0.5), "lp": jnp.float32(-1.5)}
CRITIC = {"w": jnp.array([2.0, -1.0]), "c": jnp.array([0.0, 1.0])}
TARGET = {"w": jnp.array([1.0, 2.0]), "c": jnp.array([0.5, -0.5])}
BATCH = {
    "t": jnp.array([0, 2]),
    "reward": jnp.array([-1.0, 0.0]),
    "action": jnp.array([[0.1, 0.2, 0.3], [1.0, 0.0, -1.0]]),  # sums 0.6 and 0
}
ALPHA, GAMMA = 0.5, 0.9
KEY = jax.random.PRNGKey(0)


def test_loss_arithmetic():
    # r + gamma * (min Q' - alpha logp') = -1 + 0.9 * (2 - 0.5 * -2) = 1.7
    np.testing.assert_allclose(td_target(-1.0, jnp.array([[2.0], [3.0]]), -2.0, 0.5, 0.9), [1.7], rtol=1e-6)
    # 0.5 * (mean((1-0)^2, (3-1)^2) + mean((0-0)^2, (-1-1)^2)) = 0.5 * (2.5 + 2) = 2.25
    np.testing.assert_allclose(critic_loss_value(jnp.array([[1.0, 3.0], [0.0, -1.0]]), jnp.array([0.0, 1.0])), 2.25)
    # mean(0.2 * logp - min Q) = mean(0.2 * -1 - 1, 0.2 * 0.5 - (-2)) = mean(-1.2, 2.1) = 0.45
    np.testing.assert_allclose(
        actor_loss_value(jnp.array([-1.0, 0.5]), jnp.array([[1.0, 4.0], [3.0, -2.0]]), 0.2), 0.45, rtol=1e-6
    )
    # -mean(log_alpha * (logp + H)) = -(ln 2 * mean(-1 - 3, 1 - 3)) = 3 ln 2; d/dlog_alpha = 3
    la = jnp.float32(math.log(2.0))
    value, grad = jax.value_and_grad(alpha_loss)(la, jnp.array([-1.0, 1.0]), -3.0)
    np.testing.assert_allclose([value, grad], [3 * math.log(2.0), 3.0], rtol=1e-6)


def test_critic_loss_with_stub_networks():
    loss, aux = make_critic_loss(StubNets(), GAMMA)(CRITIC, TARGET, ACTOR, ALPHA, BATCH, KEY)
    # next actions at t+1 = 1, 3: a = 0.6 and 0.8 per dim, sums 1.8 and 2.4, logp -1.5
    # target critics: Q1' = 1.8 + 0.5 = 2.3, Q2' = 3.6 - 0.5 = 3.1 -> min 2.3
    #                 Q1' = 2.4 + 1.5 = 3.9, Q2' = 4.8 - 1.5 = 3.3 -> min 3.3
    # y = -1 + 0.9 (2.3 + 0.75) = 1.745;  y = 0 + 0.9 (3.3 + 0.75) = 3.645  (no done flag: always bootstrap)
    np.testing.assert_allclose(aux["target_q"], (1.745 + 3.645) / 2, rtol=1e-6)
    # online critics at t = 0, 2 with the stored actions: Q1 = (1.2, 0), Q2 = (-0.6, 2)
    # 0.5 * [((1.2-1.745)^2 + 3.645^2) / 2 + (2.345^2 + 1.645^2) / 2] = 0.5 * (6.791525 + 4.102525)
    np.testing.assert_allclose(loss, 5.447025, rtol=1e-6)


def test_actor_loss_with_stub_networks():
    actor_loss = make_actor_loss(StubNets())
    (loss, aux), grads = jax.value_and_grad(actor_loss, has_aux=True)(ACTOR, CRITIC, ALPHA, BATCH, KEY)
    logp = aux["logp"]
    # actions at t = 0, 2: sums 1.5 and 2.1.  Q1 = (3.0, 4.2), Q2 = (-1.5, -2.1 + 2) -> min (-1.5, -0.1)
    # mean(0.5 * -1.5 - min) = mean(0.75, -0.65) = 0.05
    np.testing.assert_allclose(loss, 0.05, rtol=1e-5)
    np.testing.assert_allclose(logp, [-1.5, -1.5])
    # d/da_j of mean(-min Q) = mean(1, 1) (the min is Q2 = -sum(a) + ...); d/dlp = alpha
    np.testing.assert_allclose(grads["a"], [1.0, 1.0, 1.0], rtol=1e-6)
    np.testing.assert_allclose(grads["lp"], ALPHA, rtol=1e-6)


def test_cloning_only_actor_never_reads_the_critics():
    """sac.actor_loss 'bc': the actor's loss is the cloning term alone, so neither its value nor its
    gradient depends on the critics (SAC's objective does)."""
    demo = {"t": jnp.array([1, 3]), "action": jnp.zeros((2, 3)), "expert_action": jnp.array([[1.0, 0.0, 0.0]] * 2)}
    other = {"w": jnp.array([-3.0, 5.0]), "c": jnp.array([2.0, -2.0])}
    grad = lambda f, c: jax.value_and_grad(f, has_aux=True)(ACTOR, c, ALPHA, BATCH, KEY, demo)  # noqa: E731
    bc_only = make_actor_loss(StubNets(), bc_weight=2.0, q_filter=False, objective="bc")
    (l1, _), g1 = grad(bc_only, CRITIC)
    (l2, _), g2 = grad(bc_only, other)
    # Deterministic actions at t = 1, 3: 0.6 and 0.8 per dim; squared error to (1, 0, 0) summed over dims:
    # 0.16 + 0.36 + 0.36 = 0.88 and 0.04 + 0.64 + 0.64 = 1.32 -> mean 1.10, times bc_weight 2 = 2.2
    np.testing.assert_allclose([l1, l2], [2.2, 2.2], rtol=1e-5)
    jax.tree.map(np.testing.assert_array_equal, g1, g2)
    assert float(g1["lp"]) == 0.0  # no entropy term either
    sac = make_actor_loss(StubNets(), bc_weight=2.0, q_filter=False)
    (_, _), s1 = grad(sac, CRITIC)
    (_, _), s2 = grad(sac, other)
    assert not np.allclose(s1["a"], s2["a"])  # SAC's actor follows the critics
    with pytest.raises(ValueError, match="cloning-only actor needs bc_weight > 0 and no Q-filter"):
        make_actor_loss(StubNets(), bc_weight=2.0, q_filter=True, objective="bc")


def test_cloning_weight_follows_the_teacher_scale():
    demo = {"t": jnp.array([1, 3]), "action": jnp.zeros((2, 3)), "expert_action": jnp.array([[1.0, 0.0, 0.0]] * 2)}
    loss = make_actor_loss(StubNets(), bc_weight=2.0, q_filter=False)
    full, _ = loss(ACTOR, CRITIC, ALPHA, BATCH, KEY, demo, 1.0)
    quarter, aux = loss(ACTOR, CRITIC, ALPHA, BATCH, KEY, demo, 0.25)
    none, _ = loss(ACTOR, CRITIC, ALPHA, BATCH, KEY, demo, 0.0)
    # SAC's part is 0.05 (test_actor_loss_with_stub_networks); the cloning part 2 * 1.10 * scale.
    np.testing.assert_allclose([full, quarter, none], [0.05 + 2.2, 0.05 + 0.55, 0.05], rtol=1e-5)
    assert float(aux["bc_scale"]) == 0.25


def test_update_with_stub_networks():
    """The whole update: critic step, then the actor against the UPDATED critic, then alpha; all with
    the pre-update alpha; Polyak averaging. Adam's first step moves each parameter by lr * sign(grad)."""
    cfg = SACConfig(lr=0.1, tau=0.5, gamma=GAMMA, init_alpha=ALPHA)
    opt = make_optimizer(cfg)
    state = SACState(
        actor_params=ACTOR,
        critic_params=CRITIC,
        target_critic_params=TARGET,
        actor_opt_state=opt.init(ACTOR),
        critic_opt_state=opt.init(CRITIC),
        log_alpha=jnp.log(jnp.float32(ALPHA)),
        alpha_opt_state=opt.init(jnp.log(jnp.float32(ALPHA))),
        step=jnp.int32(0),
    )
    update = make_update(AgentConfig("vpm"), cfg, nets=StubNets())
    new, m = update(state, BATCH, KEY)
    np.testing.assert_allclose(m["critic_loss"], 5.447025, rtol=1e-6)
    np.testing.assert_allclose(m["alpha"], ALPHA, rtol=1e-6)
    # critic grads (residuals / B): dw1 = -0.545*0.6/2 < 0, dc1 = -3.645*2/2 < 0, dw2 = -2.345*0.6/2 < 0,
    # dc2 = -1.645*2/2 < 0  ->  every critic parameter rises by lr: w = (2.1, -0.9), c = (0.1, 1.1)
    np.testing.assert_allclose(new.critic_params["w"], [2.1, -0.9], rtol=1e-5)
    np.testing.assert_allclose(new.critic_params["c"], [0.1, 1.1], rtol=1e-5)
    # actor loss with the updated critics: Q2 = -0.9 * 1.5 = -1.35 and -0.9 * 2.1 + 2.2 = 0.31 (the minima)
    # mean(-0.75 + 1.35, -0.75 - 0.31) = -0.23   (with the old critics it would be 0.05)
    np.testing.assert_allclose(m["actor_loss"], -0.23, rtol=1e-5)
    np.testing.assert_allclose(new.actor_params["a"], [0.4, 0.4, 0.4], rtol=1e-5)  # grad 0.9 > 0
    np.testing.assert_allclose(new.actor_params["lp"], -1.6, rtol=1e-5)  # grad alpha > 0
    # alpha: grad = -mean(logp + H) = -(-1.5 - 3) = 4.5 > 0  ->  log_alpha falls by lr
    np.testing.assert_allclose(new.log_alpha, math.log(ALPHA) - 0.1, rtol=1e-5)
    np.testing.assert_allclose(m["alpha_loss"], -math.log(ALPHA) * -4.5, rtol=1e-5)
    # Polyak with tau 0.5: 0.5 * new + 0.5 * old target
    np.testing.assert_allclose(new.target_critic_params["w"], [1.55, 0.55], rtol=1e-5)
    np.testing.assert_allclose(new.target_critic_params["c"], [0.3, 0.3], rtol=1e-5)
    assert int(new.step) == 1


def test_update_with_real_networks(real_update):
    agent, cfg, state, batch = real_update
    new, m = jax.jit(make_update(agent, cfg))(state, batch, KEY)
    assert all(np.isfinite(float(v)) for v in m.values())
    # Polyak, tau = 0.05, target starts equal to the critics
    jax.tree.map(
        lambda t, c, c0: np.testing.assert_allclose(t, 0.05 * c + 0.95 * c0, rtol=1e-5, atol=1e-7),
        new.target_critic_params,
        new.critic_params,
        state.critic_params,
    )
    # Adam's first step on log_alpha: -lr * sign(grad), grad = -mean(logp) + 3 = entropy + 3
    np.testing.assert_allclose(new.log_alpha, -1e-3 * np.sign(float(m["entropy"]) + 3.0), rtol=1e-4)
    leaves = zip(jax.tree.leaves(new.actor_params), jax.tree.leaves(state.actor_params))
    moved = [np.abs(np.asarray(n - o)).max() for n, o in leaves]
    assert all(0 < d <= 1.0001e-3 for d in moved)


def test_lr_decays_linearly_to_zero(real_update):
    agent, cfg, state, batch = real_update
    cfg = SACConfig(batch_size=8, lr_decay=True)
    with pytest.raises(ValueError, match="total_updates"):
        make_optimizer(cfg)
    # Over 2 updates: lr, lr/2, then 0 — Adam's first steps move by exactly lr * sign(grad).
    state = init_state(jax.random.PRNGKey(0), make_networks(agent), cfg, 5, total_updates=2)
    update = jax.jit(make_update(agent, cfg, total_updates=2))
    s1, _ = update(state, batch, KEY)
    s2, _ = update(s1, batch, KEY)
    s3, _ = update(s2, batch, KEY)
    np.testing.assert_allclose(abs(float(s1.log_alpha - state.log_alpha)), 1e-3, rtol=1e-4)
    np.testing.assert_allclose(abs(float(s2.log_alpha - s1.log_alpha)), 0.5e-3, rtol=2e-2)
    jax.tree.map(np.testing.assert_array_equal, s3.actor_params, s2.actor_params)
    assert float(s3.log_alpha) == float(s2.log_alpha)


@pytest.mark.parametrize("kind", ["egru", "stacked"])
def test_the_shared_actor_pass_gives_the_two_pass_update(kind):
    """One pass of the actor's extractor for the critic's target and the actor's loss, its gradient
    carried back by a VJP, is the same step as two passes (cloning and anchor terms included)."""
    from mjx_push.train.networks import make_networks
    from mjx_push.train.sac import init_state

    agent = AgentConfig(kind, hidden=(16, 16), gru_hidden=8, obs_norm=True)
    cfg = SACConfig(batch_size=8, bc_weight=1.0, q_filter=False, anchor_weight=1.0)
    T, nets = 5, make_networks(agent)
    state = init_state(jax.random.PRNGKey(0), nets, cfg, T)
    k = jax.random.split(jax.random.PRNGKey(1), 6)

    def episodes(key, n):
        ka, kb, kc, kd = jax.random.split(key, 4)
        return {
            "ee_xy": jax.random.normal(ka, (n, T + 1, 2)),
            "z_obj": jax.random.normal(kb, (n, T + 1, 6)),
            "z_goal": jax.random.normal(kc, (n, 6)),
            "t": jax.random.randint(kd, (n,), 0, T),
            "action": jax.random.uniform(kd, (n, 3), minval=-1, maxval=1),
            "reward": -jnp.ones((n,)),
        }

    batch, demo = episodes(k[0], 8), episodes(k[1], 4)
    anchor = init_state(jax.random.PRNGKey(5), nets, cfg, T).actor_params
    steps = {
        share: jax.jit(make_update(agent, cfg, nets=nets, share_actor_pass=share))(
            state, batch, k[2], demo, 0.5, anchor, 0.5
        )
        for share in (True, False)
    }
    (shared, m_shared), (two, m_two) = steps[True], steps[False]
    for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(shared), jax.tree_util.tree_leaves(two)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6, err_msg=jax.tree_util.keystr(path))
    assert not np.allclose(
        shared.actor_params["params"]["mlp"]["Dense_0"]["kernel"],
        state.actor_params["params"]["mlp"]["Dense_0"]["kernel"],
    )  # a real step was taken
    for name in ("critic_loss", "actor_loss", "bc_loss", "anchor_drift"):
        np.testing.assert_allclose(m_shared[name], m_two[name], rtol=1e-5)

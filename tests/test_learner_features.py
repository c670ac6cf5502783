"""Learner features beyond the reference (train/normalizer.py, the privileged critic, behaviour cloning
with a Q-filter, target clipping, the success-radius curriculum, demonstrations in replay), each on
small inputs with known answers, and the whole set through the loop (its learning:
benchmarks/learning_checks.py)."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push.train import normalizer, replay
from mjx_push.train.config import AgentConfig, DemoConfig, ReplayConfig
from mjx_push.train.loop import Runner, make_train, spread_envs, train as run_train
from mjx_push.train.networks import make_networks
from mjx_push.train.sac import bc_loss_value, make_actor_loss, make_critic_loss
from tests.toy import TAU, all_features_config, make_toy

T = 6


def test_running_stats_merge_batches_exactly():
    rng = np.random.default_rng(0)
    a, b = rng.normal(2.0, 3.0, (40, 3)), rng.normal(-1.0, 0.5, (25, 3))
    s = normalizer.RunningStats.zeros(3)
    s = s.update(jnp.asarray(a), jnp.ones(40)).update(jnp.asarray(b), jnp.ones(25))
    both = np.concatenate([a, b])
    np.testing.assert_allclose(s.mean, both.mean(0), rtol=1e-5)
    np.testing.assert_allclose(s.std, both.std(0), rtol=1e-5)
    # Weight-0 samples (steps of invalid episodes) do not count.
    junk = np.full((10, 3), 1e6)
    s2 = s.update(jnp.asarray(junk), jnp.zeros(10))
    np.testing.assert_allclose(s2.mean, s.mean)
    np.testing.assert_allclose(s2.std, s.std)
    assert float(normalizer.RunningStats.zeros(2).std.min()) > 0  # never divides by zero


def _episodes(rng, n=3, priv_dim=0):
    ep = {
        "z_obj": rng.normal(size=(n, T + 1, 6)),
        "ee_xy": rng.normal(size=(n, T + 1, 2)),
        "obj_xy": rng.normal(size=(n, T + 1, 2)),
        "z_goal": rng.normal(size=(n, 6)),
        "goal_xy": rng.normal(size=(n, 2)),
        "action": rng.uniform(-1, 1, (n, T, 3)),
        "valid": np.ones(n, bool),
        "demo": np.array([True] + [False] * (n - 1)),
    }
    if priv_dim:
        ep["priv"] = rng.normal(size=(n, T + 1, priv_dim))
    return {k: jnp.asarray(v, jnp.float32 if v.dtype != bool else bool) for k, v in ep.items()}


@pytest.mark.parametrize("kind", ["vpm", "ugru"])
def test_normalised_networks_equal_the_plain_ones_on_standardised_inputs(kind):
    """An actor with obs_norm and statistics (mean, std) computes what the same weights compute without
    normalisation on clip((x - mean) / std); written statistics reach the actor, critics and targets."""
    rng = np.random.default_rng(1)
    ep = _episodes(rng, priv_dim=4)
    ep = {**ep, "ee_xy": ep["ee_xy"] * 0.1 + 0.4, "z_obj": ep["z_obj"] * 3.0 - 1.0}
    plain = make_networks(AgentConfig(kind))
    normed = make_networks(AgentConfig(kind, obs_norm=True, norm_clip=2.0))
    actor, critic = normed.init(jax.random.PRNGKey(0), T)
    stats = normalizer.update_stats(normalizer.init_stats("actor", 0), ep, "actor")
    actor = normalizer.write(actor, stats)
    critic = normalizer.write(critic, stats)
    assert critic["norm"]["norm"]["z_mean"].shape == (2, 6)  # both twins carry the statistics
    np.testing.assert_allclose(critic["norm"]["norm"]["z_std"][1], stats["z"].std, rtol=1e-6)

    def standard(x, g):
        return jnp.clip((x - stats[g].mean) / stats[g].std, -2.0, 2.0)

    idx = jnp.array([[0, 3]] * 3, jnp.int32)
    noise = jnp.zeros((3, 2, 3))
    a_norm, _ = normed.policy(actor, ep, idx, noise)
    manual = {
        **ep,
        "ee_xy": standard(ep["ee_xy"], "ee_xy"),
        "z_obj": standard(ep["z_obj"], "z"),
        "z_goal": standard(ep["z_goal"], "z"),
    }
    a_plain, _ = plain.policy({"params": actor["params"]}, manual, idx, noise)
    np.testing.assert_allclose(a_norm, a_plain, atol=1e-6)
    assert not np.allclose(a_norm, plain.policy({"params": actor["params"]}, ep, idx, noise)[0], atol=1e-3)


def test_privileged_critic_reads_ground_truth_and_goal_not_latents():
    rng = np.random.default_rng(2)
    ep = _episodes(rng, priv_dim=5)
    nets = make_networks(
        AgentConfig("egru", critic_obs="privileged", critic_layer_norm=True, critic_hidden=(32, 32)), priv_dim=5
    )
    _, critic = nets.init(jax.random.PRNGKey(0), T)
    assert "features" not in critic["params"]  # an MLP over the state: no recurrent extractor
    assert critic["params"]["mlp"]["LayerNorm_0"]["scale"].shape == (2, 32)
    idx = jnp.array([[1], [2], [3]], jnp.int32)
    act = jnp.zeros((3, 1, 3))
    q = nets.q(critic, ep, idx, act)
    assert q.shape == (2, 3, 1)
    np.testing.assert_allclose(nets.q(critic, {**ep, "z_obj": ep["z_obj"] + 5.0}, idx, act), q)  # latents unused
    assert not np.allclose(nets.q(critic, {**ep, "goal_xy": ep["goal_xy"] + 0.1}, idx, act), q)
    with pytest.raises(ValueError, match="privileged.*priv_dim"):
        make_networks(AgentConfig("vpm", critic_obs="privileged")).init(jax.random.PRNGKey(0), T)


class LinearNets:
    """Stub networks: deterministic action = a per-step constant, Q = -|action - target|^2."""

    action_dim = 2

    def deterministic_action(self, params, episode, idx):
        return jnp.broadcast_to(params["a"], idx.shape + (2,))

    def policy(self, params, episode, idx, noise):
        return self.deterministic_action(params, episode, idx), jnp.zeros(idx.shape)

    def policy_with_mode(self, params, episode, idx, noise):
        return (*self.policy(params, episode, idx, noise), self.deterministic_action(params, episode, idx))

    def q(self, params, episode, idx, action):
        v = -jnp.sum((action - episode["target"][:, None]) ** 2, -1)
        return jnp.stack([v, v])


def test_behaviour_cloning_is_q_filtered():
    demo = {
        "t": jnp.zeros(2, jnp.int32),
        "action": jnp.array([[1.0, 0.0], [0.0, 0.0]]),
        "target": jnp.array([[1.0, 0.0], [1.0, 0.0]]),
    }  # expert right on sample 0, wrong on sample 1
    batch = {"t": jnp.zeros(2, jnp.int32), "target": demo["target"]}
    params = {"a": jnp.array([0.5, 0.0])}
    loss_fn = make_actor_loss(LinearNets(), bc_weight=2.0, q_filter=True)
    (_, aux), _ = jax.value_and_grad(loss_fn, has_aux=True)(params, None, 0.0, batch, jax.random.PRNGKey(0), demo)
    # Only sample 0 passes the filter: Q(expert) = 0 > Q(actor) = -0.25; sample 1: -1 < -0.25.
    np.testing.assert_allclose(aux["bc_kept"], 0.5)
    np.testing.assert_allclose(aux["bc_loss"], 0.25 / 2)
    unfiltered = make_actor_loss(LinearNets(), bc_weight=2.0, q_filter=False)
    (_, aux), _ = jax.value_and_grad(unfiltered, has_aux=True)(params, None, 0.0, batch, jax.random.PRNGKey(0), demo)
    np.testing.assert_allclose(aux["bc_loss"], (0.25 + 0.25) / 2)
    np.testing.assert_allclose(bc_loss_value(jnp.zeros((2, 2)), jnp.ones((2, 2)), jnp.array([1.0, 0.0])), 1.0)


def test_the_anchor_takes_the_cloning_weight_as_the_teacher_goes():
    batch = {"t": jnp.zeros(2, jnp.int32), "target": jnp.zeros((2, 2))}
    params, anchor = {"a": jnp.array([0.5, 0.0])}, {"a": jnp.array([0.0, 1.0])}
    loss_fn = jax.value_and_grad(make_actor_loss(LinearNets(), anchor_weight=2.0), has_aux=True)
    key = jax.random.PRNGKey(0)
    (plain, _), _ = loss_fn(params, None, 0.0, batch, key)
    drift = 0.25 + 1.0  # |(0.5, 0) - (0, 1)|^2
    for scale in (1.0, 0.25, 0.0):
        (loss, aux), grads = loss_fn(params, None, 0.0, batch, key, None, scale, anchor)
        # While the anchor weighs nothing its pass is skipped and its drift reads 0.
        np.testing.assert_allclose(aux["anchor_drift"], drift if scale < 1.0 else 0.0)
        np.testing.assert_allclose(loss - plain, 2.0 * (1.0 - scale) * drift, rtol=1e-6)
    # At scale 0 the whole weight holds the actor: the gradient points away from the anchor (Q's own
    # gradient at target 0 is 2 * a = (1, 0); the anchor's 2 * 2 * (a - anchor) = (2, -4)).
    np.testing.assert_allclose(grads["a"], [1.0 + 2.0, -4.0], rtol=1e-6)


def test_the_anchor_lets_go_on_its_own_scale_and_a_gone_teacher_costs_no_pass():
    """anchor_scale, when given, weighs the anchor instead of 1 - bc_scale; with bc_scale 0 the cloning
    term adds nothing, to the loss or the gradient, and its pass is skipped (its metrics read 0)."""
    batch = {"t": jnp.zeros(2, jnp.int32), "target": jnp.zeros((2, 2))}
    demo = {"t": jnp.zeros(2, jnp.int32), "action": jnp.ones((2, 2)), "target": jnp.zeros((2, 2))}
    params, anchor = {"a": jnp.array([0.5, 0.0])}, {"a": jnp.array([0.0, 1.0])}
    key = jax.random.PRNGKey(0)
    both = jax.value_and_grad(make_actor_loss(LinearNets(), 2.0, False, anchor_weight=2.0), has_aux=True)
    plain = jax.value_and_grad(make_actor_loss(LinearNets()), has_aux=True)
    (base, _), base_grads = plain(params, None, 0.0, batch, key)
    drift = 0.25 + 1.0
    for anchor_scale in (1.0, 0.5, 0.0):
        (loss, aux), grads = both(params, None, 0.0, batch, key, demo, 0.0, anchor, anchor_scale)
        np.testing.assert_allclose(loss - base, 2.0 * anchor_scale * drift, rtol=1e-6)
        assert float(aux["bc_loss"]) == 0.0 and float(aux["bc_kept"]) == 0.0
        np.testing.assert_allclose(aux["anchor_scale"], anchor_scale)
    np.testing.assert_allclose(grads["a"], base_grads["a"], rtol=1e-6)  # released: SAC's gradient alone
    (loss, aux), _ = both(params, None, 0.0, batch, key, demo, 1.0, anchor, 0.0)
    np.testing.assert_allclose(aux["bc_loss"], 0.25 + 1.0)  # |(0.5, 0) - (1, 1)|^2
    np.testing.assert_allclose(loss - base, 2.0 * 1.25, rtol=1e-6)  # the teacher still counts in full


def test_target_clip_bounds_the_td_target():
    class Big(LinearNets):
        def q(self, params, episode, idx, action):
            return jnp.full((2,) + idx.shape, 100.0)

    batch = {
        "t": jnp.zeros(2, jnp.int32),
        "reward": jnp.array([-1.0, 0.0]),
        "action": jnp.zeros((2, 2)),
        "target": jnp.zeros((2, 2)),
    }
    params = {"a": jnp.zeros(2)}
    _, aux = make_critic_loss(Big(), 0.9, target_clip=True)(None, None, params, 0.0, batch, jax.random.PRNGKey(0))
    np.testing.assert_allclose(aux["target_q"], 0.0)  # 0.9 * 100 - 1 clipped to the return's maximum, 0
    _, aux = make_critic_loss(Big(), 0.9, target_clip=False)(None, None, params, 0.0, batch, jax.random.PRNGKey(0))
    np.testing.assert_allclose(aux["target_q"], 89.5)


def test_demo_batches_come_from_demonstrations_unrelabelled_and_the_radius_is_an_input():
    cfg = ReplayConfig(capacity_transitions=10 * T, her_k=4)
    buf = replay.init(cfg, T, priv_dim=3, success_tau=0.01)
    ep = _episodes(np.random.default_rng(3), n=4, priv_dim=3)
    buf = replay.add(buf, ep)
    assert int(replay.num_demo_episodes(buf)) == 1
    d = replay.sample(buf, jax.random.PRNGKey(0), 64, demos_only=True, relabel=False)
    assert set(np.asarray(d["episode"])) == {0} and not np.any(d["relabelled"])
    assert d["priv"].shape == (64, T + 1, 3)
    # The reward radius: ground-truth distances are O(1) here, so 10 m counts every step as success.
    wide = replay.sample(buf, jax.random.PRNGKey(1), 64, success_tau=10.0)
    assert np.all(wide["reward"] == 0.0)
    assert np.mean(replay.sample(buf, jax.random.PRNGKey(1), 64)["reward"]) < -0.5


def test_expert_share_of_each_batch():
    runner = Runner(make_train(all_features_config(), make_toy(success_tau=TAU)))
    assert runner.expert_envs(0).all()  # demonstrations instead of random warm-up actions
    assert np.flatnonzero(runner.expert_envs(160)).tolist() == [2, 6]  # 25 % of 8 after it, spread out


def test_expert_share_is_spread_over_the_groups_in_proportion():
    assert spread_envs(8, (16, 16)).reshape(2, 16).sum(1).tolist() == [4, 4]
    assert spread_envs(3, (5, 3)).tolist() == [False, True, False, True, False, False, True, False]
    assert spread_envs(0, (4, 4)).sum() == 0 and spread_envs(8, (4, 4)).all()
    with pytest.raises(ValueError, match="cannot pick 9 of 8 environments"):
        spread_envs(9, (4, 4))


def test_expert_demonstrates_every_shape_group_of_the_pushing_batch():
    """The `cpu` preset's batch lays out 16 cuboids then 16 cylinders: the expert's 8 environments are
    4 of each, and so is the agent's own share (12 + 12). Nothing is compiled here."""
    from mjx_push import encoder as enc
    from mjx_push.train import presets
    from mjx_push.train.push_task import make_push_adapter

    cfg = presets.make("vpm", "cpu")
    runner = Runner(make_train(cfg.train, make_push_adapter(cfg.env, enc.load(None))))
    after_warmup = runner.expert_envs(cfg.train.loop.warmup_env_steps)
    assert runner.adapter.groups(32) == (16, 16)
    assert after_warmup[:16].sum() == 4 and after_warmup[16:].sum() == 4


def test_in_run_evaluations_of_every_agent_share_the_protocol_episodes():
    """VPM (uniform sampling) and eGRU (improved sampling) are scored in training on the same objects,
    poses and goals: the protocol's episodes of loop.eval_setting / loop.eval_seed, cuboids on the even
    indices and cylinders on the odd ones, as `mjx-push eval` draws them."""
    from mjx_push import encoder as enc
    from mjx_push.train import presets
    from mjx_push.train.episodes import EvalSpec, episode_objects
    from mjx_push.train.push_task import make_push_adapter

    chunks = {}
    for agent in ("vpm", "egru"):
        cfg = presets.make(agent, "cpu", seed={"vpm": 0, "egru": 7}[agent])
        loop = cfg.train.loop
        chunks[agent] = make_push_adapter(cfg.env, enc.load(None)).eval_episodes(
            loop.eval_setting, loop.eval_seed, 1, 32
        )
    a, b = chunks["vpm"], chunks["egru"]
    assert a["index"].tolist() == list(range(32, 64, 2)) + list(range(33, 64, 2))  # chunk 1 = episodes 32..63
    jax.tree.map(np.testing.assert_array_equal, (a["keys"], a["params"]), (b["keys"], b["params"]))
    spec = EvalSpec(setting=cfg.train.loop.eval_setting, seed=cfg.train.loop.eval_seed)
    boxes, _ = episode_objects(spec, cfg.env.objects, "box", np.arange(32, 64, 2))
    np.testing.assert_array_equal(a["params"].start[:16], boxes.start)
    assert cfg.train.loop.eval_seed != EvalSpec().seed  # the report's test episodes are never the selection's


def test_annealed_teacher_leaves_the_last_batches_to_the_agent():
    cfg = dataclasses.replace(
        all_features_config(), demo=DemoConfig(warmup=True, fraction=0.5, noise=0.1, anneal_start=320, anneal_end=960)
    )
    runner = Runner(make_train(cfg, make_toy(success_tau=TAU)))
    assert [int(runner.expert_envs(s).sum()) for s in (160, 320, 640, 800, 960, 1200)] == [4, 4, 2, 1, 0, 0]


def test_the_anchor_lets_go_and_the_schedule_reads_at_chosen_env_steps():
    demo = DemoConfig(warmup=True, fraction=0.5, anneal_start=320, anneal_end=480, anchor_release=640)
    steps = (0, 320, 400, 480, 560, 640, 800)
    assert [demo.teacher_scale(s) for s in steps] == [1.0, 1.0, 0.5, 0.0, 0.0, 0.0, 0.0]
    assert [demo.anchor_scale(s) for s in steps] == [0.0, 0.0, 0.5, 1.0, 0.5, 0.0, 0.0]
    traced = [float(demo.anchor_scale(jnp.asarray(s))) for s in steps]
    assert traced == [demo.anchor_scale(s) for s in steps]  # the jitted loop reads the same schedule
    held = dataclasses.replace(demo, anchor_release=None)
    assert [held.anchor_scale(s) for s in steps] == [0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0]
    assert DemoConfig(warmup=True).anchor_scale(800) == 0.0
    assert [demo.teacher_gone(s) for s in (479, 480)] == [False, True]


@pytest.mark.parametrize(
    "fields, message",
    [
        (dict(anchor_release=900), "demo.anchor_release must be None unless the teacher is annealed"),
        (dict(keep_after_anneal=False), "demo.keep_after_anneal must be True unless the teacher is annealed"),
        (dict(anneal_start=320, anneal_end=480, anchor_release=480), "demo.anchor_release must be None or an int"),
        (dict(anneal_start=320, anneal_end=480, keep_after_anneal=0), "demo.keep_after_anneal must be a bool"),
    ],
)
def test_bad_release_settings_are_refused_by_name(fields, message):
    with pytest.raises(ValueError, match=message):
        DemoConfig(warmup=True, fraction=0.5, **fields)


def test_drop_demos_marks_only_the_demonstrations_invalid():
    rng = np.random.default_rng(0)
    buf = replay.init(ReplayConfig(capacity_transitions=6 * T), T, success_tau=0.01)
    eps = {**_episodes(rng, 3), "demo": jnp.array([True, False, True])}
    buf = replay.add(buf, eps)
    kept = replay.drop_demos(buf, jnp.asarray(False))
    assert kept.data["valid"][:3].tolist() == [True, True, True]
    gone = replay.drop_demos(buf, jnp.asarray(True))
    assert gone.data["valid"][:3].tolist() == [False, True, False]
    assert int(replay.num_demo_episodes(gone)) == 0 and int(replay.num_valid_episodes(gone)) == 1


def test_the_anchor_holds_then_lets_go_and_learning_outlives_the_demonstrations():
    """The anchor is the actor of the batch ending at anneal_start, frozen after it, its weight let go
    on the schedule. Cloning from demonstrations only (label_all off) gates updates on a demonstration
    in replay while the teacher counts; once it has gone and its episodes have left replay
    (keep_after_anneal off), the agent learns on from its own episodes."""
    cfg = dataclasses.replace(
        all_features_config(loop_over=dict(total_env_steps=800)),
        sac=dataclasses.replace(all_features_config().sac, anchor_weight=2.0),
        demo=DemoConfig(
            warmup=True,
            fraction=0.5,
            noise=0.1,
            anneal_start=320,
            anneal_end=480,
            anchor_release=640,
            keep_after_anneal=False,
        ),
    )
    runner = Runner(make_train(cfg, make_toy(success_tau=TAU)))
    state, by_step, actors = runner.init(jax.random.PRNGKey(0)), {}, {}
    while int(state.env_steps) < cfg.loop.total_env_steps:
        state, metrics = runner.iteration(state)
        by_step[int(state.env_steps)] = {k: np.asarray(v).item() for k, v in metrics.items()}
        actors[int(state.env_steps)] = [np.array(x) for x in jax.tree.leaves(state.sac.actor_params)]
    for a, b in zip(jax.tree.leaves(state.anchor_actor_params), actors[320]):
        np.testing.assert_array_equal(a, b)  # the batch ending at anneal_start, kept to the end
    assert not all(np.array_equal(a, b) for a, b in zip(actors[400], actors[320]))
    drifts = [by_step[s]["sac/anchor_drift"] for s in (400, 480, 560)]
    assert all(np.isfinite(drifts)) and max(drifts) > 0.0  # the actor moved and the term saw it
    assert by_step[400]["replay/demo_episodes"] > 0
    after = [by_step[s] for s in (480, 560, 640, 720, 800)]
    assert all(h["replay/demo_episodes"] == 0 for h in after)
    assert all(h["learning"] for h in after)
    updates = [h["updates"] for h in after]
    assert all(b - a == cfg.loop.updates_per_iteration(10) for a, b in zip(updates, updates[1:]))
    assert [h["demo/anchor_scale"] for h in after] == [1.0, 0.5, 0.0, 0.0, 0.0]
    assert all(np.isfinite(h["sac/actor_loss"]) for h in after)


def test_every_feature_together_runs_the_loop():
    """Every feature at once through the loop: demonstrations stored at their share, the curriculum's
    radius down to the task's, every stored step in the statistics and those statistics in the
    networks. Whether this learner learns the toy task: benchmarks/learning_checks.py
    (toy-all-features)."""
    cfg = all_features_config(loop_over=dict(total_env_steps=640))  # the curriculum ends at 560
    adapter = make_toy(success_tau=TAU)
    state, history = run_train(jax.random.PRNGKey(0), cfg, adapter)
    # Warm-up (160 env steps: two batches of 8) is all expert, then 2 of 8 environments a batch.
    assert [h["replay/demo_episodes"] for h in history] == [8, 16, 18, 20, 22, 24, 26, 28]
    taus = [h["replay/reward_tau"] for h in history]
    assert taus[1] > taus[-1] == pytest.approx(TAU)  # the curriculum ends at the task's radius
    assert float(state.norm_stats["ee_xy"].count) == 8 * 11 * len(history)  # every stored step counted
    norm = state.sac.actor_params["norm"]["norm"]
    np.testing.assert_allclose(norm["ee_xy_mean"], state.norm_stats["ee_xy"].mean)

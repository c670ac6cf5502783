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
from mjx_push.train.runs import policies
from mjx_push.train.config import LoopConfig
from mjx_push.train.push_task import make_push_adapter


def test_egru_trains_on_the_pushing_scene(tiny_egru_run):
    cfg, d, summary, state = tiny_egru_run
    assert cfg.env.objects.mode == "improved"  # eGRU = GRU + improved force sampling
    # Warm-up ends with the first batch (6 steps), so both batches run 2 * 3 * 0.5 = 3 updates.
    assert summary["env_steps"] == 12 and summary["updates"] == 6
    data = jax.device_get(state.buffer.data)
    valid = data["valid"]
    assert valid.sum() == 4  # two batches of two episodes, none flagged invalid
    z = data["z_obj"][valid]  # latents of every step's mask, reset observation included
    assert np.isfinite(z).all() and z.shape[1:] == (4, 6)
    # Different objects give different latents; the goal's latent is the goal mask's.
    assert np.ptp(z[:, 0], axis=0).max() > 1e-4
    assert np.isfinite(jax.tree.leaves(state.sac.actor_params)[0]).all()
    policy = policies.load_policy(d / "best_policy")
    assert policy.config.agent == "egru"


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


def test_the_actor_learns_the_experts_pushes_on_the_pushing_scene(encoder_file, xla_optimized):
    """Learning on the real scene, in minutes: expert demonstrations and labels (DAgger-style behaviour
    cloning), normalisation and the privileged critic must make the latent-observing actor act like
    the ground-truth expert on episodes it never saw. Breaks if the latents, the labels, the
    normalisation or the actor's updates stop carrying the signal."""
    import dataclasses

    from mjx_push.train import presets
    from mjx_push.train.loop import Runner, make_train

    base = presets.make("vpm", "cpu")
    T = 10  # the approach: the rod travels round the object to the push point
    # One cylinder (size, mass, friction fixed; start and goal drawn as in the task): a mapping from
    # latents to pushes that a few dozen episodes can teach.
    one = dataclasses.replace(
        base.env.objects,
        shape="cylinder",
        radius=(0.05, 0.05),
        min_height=0.05,
        max_height_cylinder=0.05,
        mass=(0.2, 0.2),
        friction=(0.5, 0.5),
    )
    env = dataclasses.replace(base.env, episode_length=T, objects=one)
    t = dataclasses.replace(
        base.train,
        # A narrower critic than the preset's (the actor learns from the labels; the critic's cost is
        # most of an update's, and this test must stay within minutes on 2 cores).
        agent=dataclasses.replace(base.train.agent, critic_hidden=(128, 128)),
        sac=dataclasses.replace(base.train.sac, batch_size=128, bc_batch_size=128, bc_weight=4.0, q_filter=False),
        replay=dataclasses.replace(base.train.replay, capacity_transitions=20_000),
        loop=LoopConfig(
            num_envs=16,
            total_env_steps=16 * T * 10,
            warmup_env_steps=16 * T,
            utd=0.5,
            eval_every_env_steps=16 * T * 10,
            eval_episodes=16,
        ),
        demo=dataclasses.replace(base.train.demo, label_all=True, fraction=1.0),
    )
    cfg = dataclasses.replace(base, env=env, train=t, encoder=None)
    adapter = make_push_adapter(cfg.env, enc.load(None), expert_config=cfg.expert)
    runner = Runner(make_train(cfg.train, adapter))
    state = runner.trainer.init(jax.random.PRNGKey(0))
    untrained = jax.tree.map(jnp.copy, state.sac.actor_params)
    history = []
    compiles = []  # large programs compiled (or loaded from the cache) after the first batch

    def on_event(event, secs, **kwargs):
        if ("backend_compile" in event and secs > 0.5) or "cache_retrieval" in event:
            compiles.append((event, round(secs, 2)))

    for i in range(t.loop.num_iterations(T)):
        if i == 1:
            jax.monitoring.register_event_duration_secs_listener(on_event)
        state, m = runner.iteration(state)
        history.append(m)
    jax.monitoring.unregister_event_duration_listener(on_event)
    # The environments are split over the host devices; the learner and the next rollout still reuse
    # the first batch's programs (argument placements that changed per batch recompiled the rollout).
    assert runner.trainer.rollout_mesh is None or runner.trainer.rollout_mesh.size == len(jax.devices())
    assert compiles == [], compiles
    assert int(history[0]["replay/demo_episodes"]) == 16
    bc = [float(m["sac/bc_loss"]) for m in history if bool(m["learning"])]
    assert bc[-1] < 0.6 * bc[0], bc

    # Fresh episodes driven by the expert (held out): how far is each actor from its labels?
    episodes, _ = runner.rollout(
        state.sac.actor_params, jax.random.PRNGKey(99), jnp.asarray(False), jnp.asarray(True), jnp.ones(16, bool)
    )
    nets = runner.trainer.networks
    idx = jnp.tile(jnp.arange(T)[None], (16, 1))

    def error(actor):
        a = nets.deterministic_action(actor, episodes, idx)
        return float(jnp.mean(jnp.sum((a - episodes["expert_action"]) ** 2, -1)))

    before, after = error(untrained), error(state.sac.actor_params)
    labels = episodes["expert_action"].reshape(-1, 3)
    constant = float(jnp.mean(jnp.sum((labels - labels.mean(0)) ** 2, -1)))  # the best state-blind actor

    def direction(actor):  # mean cosine between the actor's and the expert's flange moves
        a = nets.deterministic_action(actor, episodes, idx)[..., :2].reshape(-1, 2)
        e = labels[:, :2]
        return float(jnp.mean(jnp.sum(a * e, -1) / (jnp.linalg.norm(a, axis=-1) * jnp.linalg.norm(e, axis=-1) + 1e-6)))

    cos_before, cos_after = direction(untrained), direction(state.sac.actor_params)
    print(
        f"imitation error on held-out expert episodes: untrained {before:.3f}, best constant {constant:.3f}, "
        f"trained {after:.3f}; direction cosine {cos_before:.2f} -> {cos_after:.2f}; training bc loss {bc}"
    )
    assert after < 0.6 * constant < 0.6 * before
    assert cos_after > 0.7 and cos_after > cos_before + 0.5

    # In-run evaluation runs the protocol's episodes through the same compiled rollout, in their order.
    from mjx_push.train.episodes import EvalSpec, episode_objects

    ev = runner.evaluate(untrained)
    loop = cfg.train.loop
    want, _ = episode_objects(
        EvalSpec(setting=loop.eval_setting, shape="cylinder", seed=loop.eval_seed),
        cfg.env.objects,
        "cylinder",
        np.arange(16),
    )
    np.testing.assert_allclose(
        ev["episode_start_distance"], np.linalg.norm(want.start[:, :2] - want.goal[:, :2], axis=-1), rtol=1e-5
    )

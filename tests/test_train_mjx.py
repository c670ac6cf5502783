"""End to end on the MJX scene: masks -> encoder -> SAC + HER -> checkpoint and policy, at a tiny size
(2 environments, 3-step episodes) so that compilation, not simulation, is the cost."""

import train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import encoder as enc
from train import presets, run as run_mod
from train.config import LoopConfig, ReplayConfig, SACConfig
from train.push_task import make_push_adapter


def tiny(agent: str, encoder_path: str) -> presets.RunConfig:
    cfg = presets.make(agent, "smoke")
    env = dataclasses.replace(cfg.env, episode_length=3, substeps=(10, 30))
    t = dataclasses.replace(
        cfg.train,
        sac=SACConfig(batch_size=4),
        replay=ReplayConfig(capacity_transitions=60),
        loop=LoopConfig(num_envs=2, episode_len=3, total_env_steps=12, warmup_env_steps=6, utd=0.5,
                        eval_every_env_steps=6, eval_episodes=2),
    )
    return dataclasses.replace(cfg, env=env, train=t, encoder=encoder_path)


@pytest.fixture(scope="module")
def encoder_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("enc") / "encoder.msgpack"
    enc.save(path, enc.init_vae(jax.random.PRNGKey(0))["encoder"], {"seed": 0})
    return str(path)


@pytest.fixture(scope="module")
def egru_run(tmp_path_factory, encoder_file):
    cfg = tiny("egru", encoder_file)
    d = tmp_path_factory.mktemp("egru")
    summary, state = run_mod.run(cfg, d)
    return cfg, d, summary, state


def test_egru_trains_on_the_pushing_scene(egru_run):
    cfg, d, summary, state = egru_run
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
    policy = run_mod.load_policy(d / "best_policy")
    assert policy.config.agent == "egru"


def test_adapter_latents_are_the_encoder_of_the_masks(encoder_file):
    cfg = tiny("vpm", encoder_file)
    params = enc.load(encoder_file)
    adapter = make_push_adapter(cfg.env, params)
    from mjx_push.batch import PushBatch

    key = jax.random.PRNGKey(3)
    s, obs, info = jax.jit(adapter.reset, static_argnums=1)(key, 2)
    ref = PushBatch(cfg.env, 2).reset(key)  # the same environments, unencoded
    np.testing.assert_allclose(obs["z_obj"], enc.encode(params, ref.obs["object_mask"]), atol=1e-5)
    np.testing.assert_allclose(info["z_goal"], enc.encode(params, ref.obs["goal_mask"]), atol=1e-5)
    np.testing.assert_allclose(obs["obj_xy"], ref.info("object_xy"))
    np.testing.assert_allclose(info["goal_xy"], ref.info("goal_xy"))
    assert obs["ee_xy"].shape == (2, 2) and jnp.all(jnp.isfinite(obs["ee_xy"]))

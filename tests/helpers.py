"""Test helpers: a per-shape compiled simulator with a fixed batch size and object builders."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjx_push import objects, scene
from mjx_push.env import EnvConfig, PushEnv
from tests.toy import TAU as TOY_TAU  # one toy radius for the tests and the learning checks


def use_test_compilation(disable_optimizations: bool = True) -> None:
    """The suite's compilation settings, in the test process (tests/conftest.py) and the processes its
    tests start, so that all of them share compiled programs. A persistent cache: repeated local runs
    skip most compilation and a cold run fills it (MJX_PUSH_TEST_CACHE points it elsewhere, e.g. an
    empty folder to time a cold run as CI sees it). Programs under 2 s to compile stay out of it: with
    every program cached (the eager operations on sharded arrays included) a cold two-worker run once
    aborted in a two-device test and hung in another (the abort recurred without caching them: most
    likely the collective stall tests/test_data_parallel.py describes). Compilation, not execution, is most of the
    suite's time on CPU, and XLA's optimisation passes most of compilation (an MJX step compiles in
    about half the time without them and runs at half the speed, which the tests' few substeps do not
    notice); the programs compute the same. MJX_PUSH_TEST_OPTIMIZE=1 keeps them."""
    import os

    jax.config.update(
        "jax_compilation_cache_dir",
        os.environ.get("MJX_PUSH_TEST_CACHE", os.path.expanduser("~/.cache/mjx_push/jax_tests")),
    )
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)
    if disable_optimizations and os.environ.get("MJX_PUSH_TEST_OPTIMIZE") != "1":
        jax.config.update("jax_disable_most_optimizations", True)


B = 4  # every physics test uses this batch size, so each compiled function is built once
HOME_XY = scene.home_flange_pos()[:2]


def make_params(
    geom_type: str,
    *,
    sides=(0.08, 0.06),
    radius=0.05,
    height=0.05,
    mass=0.2,
    friction=0.5,
    start=(0.1, 0.08, 0.0),
    goal=(0.05, -0.05, 0.0),
) -> objects.ObjectParams:
    """One object; start and goal are offsets from the home flange xy plus a yaw."""
    if geom_type == "box":
        size = np.array([sides[0] / 2, sides[1] / 2, height / 2])
        inertia = (
            mass / 12 * np.array([sides[1] ** 2 + height**2, sides[0] ** 2 + height**2, sides[0] ** 2 + sides[1] ** 2])
        )
    else:
        size = np.array([radius, height / 2, 0.0])
        ixx = mass * (3 * radius**2 + height**2) / 12
        inertia = np.array([ixx, ixx, mass * radius**2 / 2])
    s = np.array([HOME_XY[0] + start[0], HOME_XY[1] + start[1], start[2]])
    g = np.array([HOME_XY[0] + goal[0], HOME_XY[1] + goal[1], goal[2]])
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return objects.ObjectParams(
        size=f(size),
        mass=f(mass),
        inertia=f(inertia),
        friction=f([friction, 0.005, scene.OBJECT_ROLL_FRICTION]),
        start=f(s),
        goal=f(g),
    )


def stack(params_list):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *params_list)


def action_for(ee_xy, target_xy, a_s):
    """Action (B, 3) commanding absolute flange targets with action_scale 1."""
    return jnp.concatenate([jnp.asarray(target_xy) - jnp.asarray(ee_xy), jnp.full((ee_xy.shape[0], 1), a_s)], axis=1)


def a_s_for(n: int, lo: int = 10, hi: int = 600) -> float:
    """An a_s value that decodes to exactly n substeps."""
    return 2.0 * (n + 0.5 - lo) / (hi - lo) - 1.0


class Sim:
    def __init__(self, geom_type: str, config: EnvConfig = EnvConfig()):
        self.env = PushEnv(config, geom_type)
        self.geom_type = geom_type
        self.reset_with = jax.jit(jax.vmap(self.env.reset_with))
        self.step = jax.jit(jax.vmap(self.env.step))

    def start(self, params_list, seed: int = 0):
        assert len(params_list) == B
        return self.reset_with(jax.random.split(jax.random.PRNGKey(seed), B), stack(params_list))


def tiny_run_config(agent: str, encoder_path: str, num_envs: int = 4):
    """Two batches of ``num_envs`` environments (the first the warm-up), 3-step episodes of 10-30
    substeps: compilation, not simulation, costs. Four environments (two cuboids, two cylinders) are
    the fewest a run splits over 2 host devices by whole episodes, as every one-device CPU run does, so
    the tiny eGRU run's rollout is the program the split's tests compile (one worker compiles it once:
    tests/test_tiny_egru_run.py)."""
    import dataclasses

    from mjx_push.train import presets
    from mjx_push.train.config import LoopConfig, ReplayConfig

    cfg = presets.make(agent, "smoke")
    env = dataclasses.replace(cfg.env, episode_length=3, substeps=(10, 30))
    batch = 3 * num_envs
    t = dataclasses.replace(
        cfg.train,
        sac=dataclasses.replace(cfg.train.sac, batch_size=4, bc_batch_size=4),
        replay=ReplayConfig(capacity_transitions=60),
        loop=LoopConfig(
            num_envs=num_envs,
            total_env_steps=2 * batch,
            warmup_env_steps=batch,
            utd=0.5,
            eval_every_env_steps=batch,
            eval_episodes=2,
        ),
    )
    return dataclasses.replace(cfg, env=env, train=t, encoder=encoder_path)


def toy_run_config(encoder, kind="ugru", seed=0):
    """A run of the toy task (tests/toy.py): 5 batches of 4 environments x 10 steps, evaluations at 80,
    160 and 200 env steps. The measured presets' learner (normalisation, privileged critic,
    demonstrations with behaviour cloning), so checkpoints and saved policies carry all it adds."""
    from mjx_push.train.config import AgentConfig, DemoConfig, LoopConfig, ReplayConfig, SACConfig, TrainConfig
    from mjx_push.train.config import RunConfig

    train_cfg = TrainConfig(
        agent=AgentConfig(
            kind,
            hidden=(32, 32),
            gru_hidden=8,
            critic_hidden=(32, 32),
            obs_norm=True,
            critic_obs="privileged",
            critic_layer_norm=True,
        ),
        sac=SACConfig(batch_size=16, bc_weight=1.0, bc_batch_size=8, target_clip=True),
        demo=DemoConfig(warmup=True, fraction=0.25, noise=0.1, label_all=True),
        replay=ReplayConfig(capacity_transitions=2_000),
        loop=LoopConfig(
            num_envs=4,
            total_env_steps=200,
            warmup_env_steps=80,
            utd=0.25,
            eval_every_env_steps=80,
            eval_episodes=6,
            seed=seed,
        ),
    )
    return RunConfig(
        agent=kind,
        preset="smoke",
        train=train_cfg,
        env=EnvConfig(episode_length=10, success_tau=TOY_TAU),
        encoder=encoder,
    )


def latest_state(run_dir, cfg, adapter, step=None):
    """The TrainState of a run's latest checkpoint, or the one at `step` (`adapter`: the environment it
    trained on)."""
    from mjx_push.train.runs import checkpoints
    from mjx_push.train.loop import make_train

    trainer = make_train(cfg.train, adapter)
    template = trainer.init(jax.random.PRNGKey(0))
    return checkpoints.Checkpoints(Path(run_dir) / "checkpoints").restore(template, cfg, step)[0]


def renderer_or_skip() -> None:
    """Skip a test that needs MuJoCo's offscreen renderer where there is none, but fail instead when
    MJX_PUSH_REQUIRE_RENDERER=1 (.ci/run sets it: CI machines have EGL, so a skip there would hide a
    broken renderer). renderer_available() tries once per process: MuJoCo aborts on a second failure."""
    from mjx_push.export.cpu_env import renderer_available

    if not renderer_available():
        no_renderer("no EGL / OSMesa / display")


def no_renderer(why: str) -> None:
    """Skip (or, under MJX_PUSH_REQUIRE_RENDERER=1, fail) a test whose renderer could not start."""
    import os

    import pytest

    message = f"MuJoCo offscreen renderer unavailable ({why}); set MUJOCO_GL=egl"
    if os.environ.get("MJX_PUSH_REQUIRE_RENDERER") == "1":
        pytest.fail(message + " (MJX_PUSH_REQUIRE_RENDERER=1: this machine must render)")
    pytest.skip(message)

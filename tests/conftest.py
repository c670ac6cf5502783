"""Shared fixtures. JAX compilation dominates test time on CPU, so every compiled function lives in a
session-scoped fixture and keeps one batch size."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mjx_push  # noqa: E402  (applies the CPU XLA flag before jax starts)

mjx_push.xla.use_cpu_devices()  # as the command line does: one CPU device per core (test_batch splits over 2)
import jax  # noqa: E402
import pytest  # noqa: E402

from tests.helpers import Sim, use_test_compilation  # noqa: E402

use_test_compilation()  # the cache, every program in it, most optimisations off (tests/helpers.py)


# Longest files first. Two workers take whole files (--dist loadfile) in collection order, so a long
# file collected last runs alone at the end (a long file alphabetically last once kept one core idle
# for the last ~4 minutes of a cold run). Measured per file: python -m benchmarks.suite_compiles.
_LONGEST_FIRST = (
    "test_batch.py",
    "test_run.py",
    "test_tiny_egru_run.py",
    "test_physics.py",
    "test_stress.py",
    "test_learner_features.py",
    "test_data_parallel.py",
)


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """Two worker processes, whole files each (a file's fixtures are compiled once; CI has two cores),
    when pytest-xdist is installed and `-n` was not given; without xdist the suite runs in one process
    (addopts cannot say `-n 2`: pytest rejects the option when the plugin is missing)."""
    if (
        config.pluginmanager.hasplugin("xdist")
        and not hasattr(config, "workerinput")
        and config.option.numprocesses is None
    ):
        config.option.numprocesses = 2
        if config.option.dist == "no":
            config.option.dist = "loadfile"


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(_LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(_LONGEST_FIRST)))  # stable: the rest as collected


@pytest.fixture(scope="session")
def box_sim() -> Sim:
    return Sim("box")


@pytest.fixture(scope="session")
def cyl_sim() -> Sim:
    return Sim("cylinder")


@pytest.fixture(scope="session")
def encoder_file(tmp_path_factory) -> str:
    """An untrained encoder (tests of plumbing must not depend on the shipped weights)."""
    from mjx_push import encoder as enc

    path = tmp_path_factory.mktemp("enc") / "encoder.msgpack"
    enc.save(path, enc.init_vae(jax.random.PRNGKey(0))["encoder"], {"seed": 0, "command": "test"})
    return str(path)


@pytest.fixture(scope="session")
def tiny_egru_run(tmp_path_factory, encoder_file):
    """An eGRU trained end to end on the MJX scene at a tiny size: (config, run dir, summary, state)."""
    from mjx_push.train.runs import run as run_mod
    from tests.helpers import tiny_run_config

    cfg = tiny_run_config("egru", encoder_file)
    d = tmp_path_factory.mktemp("egru")
    summary, state = run_mod.run(cfg, d)
    return cfg, d, summary, state


@pytest.fixture(scope="session")
def real_update():
    """(agent, SAC config, initial SACState, a batch of 8 random transitions) of a small VPM: the
    update tests of train/sac.py and of its data-parallel use share it."""
    import jax.numpy as jnp

    from mjx_push.train.config import AgentConfig, SACConfig
    from mjx_push.train.networks import make_networks
    from mjx_push.train.sac import init_state

    agent, cfg, T = AgentConfig("vpm", hidden=(32, 32)), SACConfig(batch_size=8), 5
    nets = make_networks(agent)
    state = init_state(jax.random.PRNGKey(0), nets, cfg, T)
    k = jax.random.split(jax.random.PRNGKey(1), 4)
    batch = {
        "ee_xy": jax.random.normal(k[0], (8, T + 1, 2)),
        "z_obj": jax.random.normal(k[1], (8, T + 1, 6)),
        "z_goal": jax.random.normal(k[2], (8, 6)),
        "t": jax.random.randint(k[3], (8,), 0, T),
        "action": jnp.zeros((8, 3)),
        "reward": -jnp.ones((8,)),
    }
    return agent, cfg, state, batch

"""Shared fixtures. JAX compilation dominates test time on CPU, so every compiled function lives in a
session-scoped fixture and keeps one batch size."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mjx_push  # noqa: E402,F401  (applies the CPU XLA flag before jax starts)
import jax  # noqa: E402
import pytest  # noqa: E402

from tests.helpers import Sim  # noqa: E402

# Persistent compilation cache: repeated local runs skip most compilation; a fresh CI run fills it.
jax.config.update("jax_compilation_cache_dir", os.path.expanduser("~/.cache/mjx_push/jax_tests"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)


@pytest.fixture(scope="session")
def box_sim() -> Sim:
    return Sim("box")


@pytest.fixture(scope="session")
def cyl_sim() -> Sim:
    return Sim("cylinder")

"""The CPU XLA flags and the command line's compilation cache (no compilation here but of a one-line
function)."""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import xla
from mjx_push.train import compile_cache


def test_cpu_device_count_reads_the_override_and_rejects_nonsense(monkeypatch):
    monkeypatch.setenv(xla.DEVICES_ENV, "3")
    assert xla.cpu_device_count() == 3
    for bad in ("0", "-2", "two", ""):
        monkeypatch.setenv(xla.DEVICES_ENV, bad)
        with pytest.raises(ValueError, match=xla.DEVICES_ENV):
            xla.cpu_device_count()
    monkeypatch.delenv(xla.DEVICES_ENV)
    assert 1 <= xla.cpu_device_count() <= xla.MAX_DEVICES


def test_flags_are_added_once_and_a_users_own_setting_wins(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", f"{xla.DEVICE_FLAG}=5")
    monkeypatch.setenv(xla.DEVICES_ENV, "2")
    xla.apply_fusion_flag()
    assert xla.use_cpu_devices() is None  # the user's own count
    flags = os.environ["XLA_FLAGS"]
    assert f"{xla.DEVICE_FLAG}=5" in flags and flags.count(xla.DEVICE_FLAG) == 1
    # The fusion-emitter flag where the installed jaxlib has it (0.10 line); jaxlib 0.11 aborts on it.
    assert (f"{xla.FLAG}=false" in flags) == xla.needs_fusion_flag()
    xla.apply_fusion_flag()
    assert os.environ["XLA_FLAGS"] == flags
    # This process's backend started long ago: asking now would change nothing, so nothing is written.
    monkeypatch.setenv("XLA_FLAGS", "")
    jax.devices()
    assert xla.use_cpu_devices() is None and os.environ["XLA_FLAGS"] == ""


def test_importing_the_package_leaves_the_device_count_to_the_program():
    """`import mjx_push` keeps jax.device_count() (a library must not change it); use_cpu_devices() before
    jax starts splits the CPU into the devices asked for, so no import may start the backend (a module-level
    jnp array would, and the command line's split would silently not happen)."""
    code = (
        "import sys, mjx_push, jax, jax._src.xla_bridge as xb, mjx_push.cli, mjx_push.brax_env\n"
        "assert not xb.backends_are_initialized(), 'an import started the backend: too late to split'\n"
        "if sys.argv[1] == 'ask': assert mjx_push.xla.use_cpu_devices(3) == 3\n"
        "print(jax.device_count(), '--xla_cpu_use_fusion_emitters' in __import__('os').environ['XLA_FLAGS'])"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", xla.DEVICES_ENV)}
    env["JAX_PLATFORMS"] = "cpu"
    for arg, want in (("import", "1"), ("ask", "3")):
        r = subprocess.run([sys.executable, "-c", code, arg], env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        assert r.stdout.split() == [want, str(xla.needs_fusion_flag())], (arg, r.stdout)


def test_the_fusion_flag_follows_the_jaxlib_line(monkeypatch):
    versions = {"0.10.2": True, "0.10.0": True, "0.9.1": True, "0.11.2": False, "0.12.0.1": False, "1.0.0": False}
    for v, want in versions.items():
        monkeypatch.setattr(xla.importlib.metadata, "version", lambda name, v=v: v)
        assert xla.needs_fusion_flag() is want, v


def test_programs_without_physics_get_the_fusion_emitters_back_only_where_the_package_took_them(monkeypatch):
    jax.devices()  # the backend starts with the suite's flags, before this test rewrites them
    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.delenv(xla.FLAG_OWNER_ENV, raising=False)
    xla.apply_fusion_flag()  # the package's flag is marked as its own, and started processes inherit the mark
    assert (os.environ.get(xla.FLAG_OWNER_ENV) == "package") == xla.needs_fusion_flag()
    monkeypatch.setenv("XLA_FLAGS", f"{xla.FLAG}=false")
    monkeypatch.setenv(xla.FLAG_OWNER_ENV, "package")
    options = xla.physics_free_options()
    assert options == ({"xla_cpu_use_fusion_emitters": True} if jax.default_backend() == "cpu" else None)
    # XLA knows the option by that name (it refuses names it does not know), and the results stand.
    x = jnp.linspace(-3.0, 3.0, 64)
    f = lambda x: jnp.tanh(x) * jnp.exp(-x * x) + 1.0  # noqa: E731
    np.testing.assert_allclose(jax.jit(f, compiler_options=options)(x), jax.jit(f)(x), rtol=1e-6, atol=1e-6)
    # A setting of the user's own, either way, holds for every program.
    monkeypatch.delenv(xla.FLAG_OWNER_ENV)
    assert xla.physics_free_options() is None
    monkeypatch.setenv(xla.FLAG_OWNER_ENV, "package")
    monkeypatch.setenv("XLA_FLAGS", f"{xla.FLAG}=true")
    assert xla.physics_free_options() is None


@pytest.fixture
def no_cache_configured():
    """No cache folder configured, as in a fresh `mjx-push` process; the suite's own cache after."""
    env, names = dict(os.environ), ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs")
    before = {n: getattr(jax.config, n) for n in names}
    jax.config.update("jax_compilation_cache_dir", None)
    os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    yield
    for n, v in before.items():
        jax.config.update(n, v)
    os.environ.clear()
    os.environ.update(env)


def test_compile_cache_follows_the_variable_and_can_be_turned_off(monkeypatch, tmp_path, no_cache_configured):
    monkeypatch.setenv(compile_cache.ENV, "off")
    assert compile_cache.enable() is None and not jax.config.jax_compilation_cache_dir
    monkeypatch.setenv(compile_cache.ENV, str(tmp_path / "cache"))
    assert compile_cache.enable() == tmp_path / "cache"
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "cache")
    assert os.environ["JAX_COMPILATION_CACHE_DIR"] == str(tmp_path / "cache")  # spawned workers read it
    # A folder already configured (by the user, or a program importing us) is kept.
    monkeypatch.setenv(compile_cache.ENV, str(tmp_path / "other"))
    assert compile_cache.enable() == tmp_path / "cache"

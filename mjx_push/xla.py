"""CPU XLA flags: one the package applies on import, one its entry points ask for.

- `--xla_cpu_use_fusion_emitters=false`, added when `mjx_push` is imported (before jax starts): with
  jaxlib 0.10.x the CPU fusion emitters make MJX kinematics exponentially slow in the depth of the
  kinematic tree (jax-ml/jax#33761, google-deepmind/mujoco#2957): a 7-joint arm runs ~500x slower.
  jaxlib 0.11 no longer knows the flag (an unknown flag in XLA_FLAGS aborts the process), so it is added
  for jaxlib < 0.11 only.
- `--xla_force_host_platform_device_count=N`, added only by `use_cpu_devices()`, which the entry points
  call (the `mjx-push` command, `benchmarks/`, the test suite): XLA runs one CPU device's program on one
  core, so a batch of MJX environments on one device uses one core however many the machine has. With N
  host devices `mjx_push.batch.PushBatch` splits its environments over them (`mjx_push.devices`) and
  the physics runs on N cores at once (1.7x on 2 cores, `benchmarks/sim_speed.py`). N is the number of
  cores this process may use, capped at 8; `MJX_PUSH_CPU_DEVICES=N` overrides it (1 turns the split
  off). A program that only imports the package keeps its own `jax.device_count()`; it can call
  `mjx_push.xla.use_cpu_devices()` itself, first. Only the CPU platform is affected.

Either flag is left alone when the user's own XLA_FLAGS already sets it either way.

The fusion-emitter flag is for MJX; programs without it (the learner's updates) compile and run faster
with the emitters, so where the package set the flag it turns them back on for those programs alone:
`physics_free_options()` is the `compiler_options` of their `jax.jit`.
"""

import importlib.metadata
import os
import sys
from mjx_push.errors import ConfigError

FLAG = "--xla_cpu_use_fusion_emitters"
# Set beside FLAG when the package added it, so that processes it starts (which inherit XLA_FLAGS with
# the flag in it) still know the flag was the package's choice and not the user's.
FLAG_OWNER_ENV = "MJX_PUSH_FUSION_FLAG"
DEVICE_FLAG = "--xla_force_host_platform_device_count"
DEVICES_ENV = "MJX_PUSH_CPU_DEVICES"
MAX_DEVICES = 8


def cpu_device_count() -> int:
    """Host devices to ask for: `MJX_PUSH_CPU_DEVICES`, else the usable cores (at most 8)."""
    value = os.environ.get(DEVICES_ENV)
    if value is not None:
        try:
            n = int(value)
        except ValueError:
            n = 0
        if n < 1:
            raise ConfigError(f"{DEVICES_ENV} must be a positive integer, got {value!r}")
        return n
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, MAX_DEVICES))


def jaxlib_line() -> tuple[int, int] | None:
    """(major, minor) of the installed jaxlib, read without importing it; None if unknown."""
    try:
        major, minor = (int(x) for x in importlib.metadata.version("jaxlib").split(".")[:2])
    except (importlib.metadata.PackageNotFoundError, ValueError):
        return None
    return major, minor


def needs_fusion_flag() -> bool:
    """Whether the installed jaxlib has (and needs) the fusion-emitter flag: the 0.10 line and older
    (an unknown build keeps the flag the tested line needs)."""
    line = jaxlib_line()
    return line is None or line < (0, 11)


def apply_fusion_flag() -> None:
    """Add the fusion-emitter flag to XLA_FLAGS where the jaxlib line needs it (run on import)."""
    flags = os.environ.get("XLA_FLAGS", "")
    if FLAG not in flags and needs_fusion_flag():
        os.environ["XLA_FLAGS"] = f"{flags} {FLAG}=false".strip()
        os.environ[FLAG_OWNER_ENV] = "package"


def physics_free_options() -> dict | None:
    """`jax.jit`'s `compiler_options` for a program that steps no MJX physics: the CPU fusion emitters
    on again where the package (not the user's XLA_FLAGS) turned them off; None elsewhere (another
    backend, a jaxlib without the flag, the user's own setting)."""
    if os.environ.get(FLAG_OWNER_ENV) != "package" or f"{FLAG}=false" not in os.environ.get("XLA_FLAGS", ""):
        return None
    import jax

    if jax.default_backend() != "cpu":
        return None
    return {FLAG.removeprefix("--"): True}


def _backend_started() -> bool:
    bridge = sys.modules.get("jax._src.xla_bridge")
    started = getattr(bridge, "backends_are_initialized", None)
    return bool(started and started())


def use_cpu_devices(n: int | None = None) -> int | None:
    """Ask XLA for `n` CPU devices (default `cpu_device_count()`), so batches split over the cores.
    Call it before anything starts JAX's backend (the first `jax.devices()`, array or compilation);
    spawned worker processes inherit it through the environment. Returns the count asked for, or None
    when nothing changed: the user's XLA_FLAGS already sets a count, or the backend has started."""
    flags = os.environ.get("XLA_FLAGS", "")
    if DEVICE_FLAG in flags or _backend_started():
        return None
    n = cpu_device_count() if n is None else n
    if n < 1:
        raise ConfigError(f"use_cpu_devices: the device count must be >= 1, got {n}")
    os.environ["XLA_FLAGS"] = f"{flags} {DEVICE_FLAG}={n}".strip()
    return n


apply_fusion_flag()

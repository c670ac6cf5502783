"""A persistent JAX compilation cache for the command line, on by default.

On a CPU most of a short run's first minutes are XLA compiling the environment's rollout and the
learner's update; those executables depend only on the configuration's shapes and the machine, so a
second run of the same preset (or an evaluation after a training) loads them from disk instead.
`MJX_PUSH_COMPILE_CACHE` moves the cache (a folder) or turns it off (`off`); a cache folder already
configured for JAX (`JAX_COMPILATION_CACHE_DIR`, or by the program importing us) is left as it is.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV = "MJX_PUSH_COMPILE_CACHE"
DEFAULT = Path("~/.cache/mjx_push/jax").expanduser()
# Only programs that took this long to compile are written: small ones cost more to store than to rebuild.
MIN_COMPILE_SECS = 1.0


def enable() -> Path | None:
    """Point JAX (this process and the worker processes it spawns) at the cache; returns its folder,
    or None when turned off."""
    import jax

    current = jax.config.jax_compilation_cache_dir
    if current:
        return Path(current)
    value = os.environ.get(ENV, str(DEFAULT))
    if value.strip().lower() in ("off", "0", "none", ""):
        return None
    folder = Path(value).expanduser()
    # The environment variables reach spawned workers (reproduce --jobs), which read them at import.
    os.environ["JAX_COMPILATION_CACHE_DIR"] = str(folder)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", str(MIN_COMPILE_SECS))
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update(
        "jax_persistent_cache_min_compile_time_secs", float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"])
    )
    return folder

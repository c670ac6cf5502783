"""mjx_push: the batched Franka Panda pushing scene in MuJoCo MJX (simulation only, no learning)."""

import contextlib as _contextlib
import io as _io

from mjx_push import xla as _xla  # noqa: F401  (must run before jax initialises)

# mujoco.mjx prints "Failed to import warp" twice on every import when the optional NVIDIA Warp
# backend is absent; we never use it, so keep that out of users' terminals.
with _contextlib.redirect_stdout(_io.StringIO()):
    import mujoco.mjx  # noqa: F401,E402

__version__ = "0.1.0"

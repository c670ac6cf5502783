"""mjx_push: the batched Franka Panda pushing scene in MuJoCo MJX (simulation only, no learning)."""

import contextlib as _contextlib
import io as _io
import os as _os
import sys as _sys

from mjx_push import xla as _xla  # noqa: F401  (must run before jax initialises)

# MuJoCo picks its OpenGL backend when first imported; on a Linux machine without a display the default
# (GLFW) cannot render, so choose EGL there unless the user chose.
if _sys.platform.startswith("linux") and not _os.environ.get("DISPLAY") and "mujoco" not in _sys.modules:
    _os.environ.setdefault("MUJOCO_GL", "egl")

# mujoco.mjx prints "Failed to import warp" twice on every import when the optional NVIDIA Warp
# backend is absent; we never use it, so keep that out of users' terminals.
with _contextlib.redirect_stdout(_io.StringIO()):
    import mujoco.mjx  # noqa: F401,E402

__version__ = "0.1.0"

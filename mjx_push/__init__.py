"""mjx_push: the batched Franka Panda pushing scene in MuJoCo MJX (simulation only, no learning).

What importing the package changes in the process, all of it here:
- XLA_FLAGS gains `--xla_cpu_use_fusion_emitters=false` on jaxlib 0.10 (`mjx_push.xla`: without it CPU
  MJX runs ~500x slower on the 7-joint arm). The split of CPU batches over one device per core is not
  applied on import: entry points call `mjx_push.xla.use_cpu_devices()`.
- MUJOCO_GL defaults to "egl" on a Linux machine without a display (GLFW cannot render there).
- mujoco.mjx's "Failed to import warp" lines are kept off stdout when it is imported (an import hook:
  the package itself imports neither MuJoCo nor JAX, so `mjx_push.errors` costs a NumPy-only program
  nothing).
- Importing `mjx_push.brax_env` (not the package) gives jax >= 0.10 back `jax.device_put_replicated`,
  which brax 0.14.2's trainers call.
"""

import contextlib as _contextlib
import importlib.abc as _abc
import io as _io
import os as _os
import sys as _sys

from mjx_push import xla as _xla  # noqa: F401  (the fusion-emitter flag: before jax initialises)

# MuJoCo picks its OpenGL backend when first imported; on a Linux machine without a display the default
# (GLFW) cannot render, so choose EGL there unless the user chose.
if _sys.platform.startswith("linux") and not _os.environ.get("DISPLAY") and "mujoco" not in _sys.modules:
    _os.environ.setdefault("MUJOCO_GL", "egl")


class _QuietWarpImport(_abc.MetaPathFinder):
    """mujoco.mjx prints "Failed to import warp" twice when the optional NVIDIA Warp backend is absent
    (its `mujoco.mjx.warp` module, run on every `import mujoco.mjx`); we never use Warp, so that module
    runs with stdout held. Found as usual by the other finders; removed once it has run."""

    def find_spec(self, name, path=None, target=None):
        if name != "mujoco.mjx.warp":
            return None
        _sys.meta_path.remove(self)
        import importlib.util

        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None:
            run = spec.loader.exec_module

            def quiet(module):
                with _contextlib.redirect_stdout(_io.StringIO()):
                    run(module)

            spec.loader.exec_module = quiet
        return spec


if "mujoco.mjx.warp" not in _sys.modules:
    _sys.meta_path.insert(0, _QuietWarpImport())

__version__ = "0.1.0"

"""MuJoCo's offscreen renderer, created with care (videos, the CPU environment's rendered masks).

On a Linux machine without a display MuJoCo needs EGL, chosen by `MUJOCO_GL=egl` before mujoco is first
imported: `import mjx_push` (and so `import export`) sets it. The first failure to create a renderer is
remembered for the whole process, because after one failed attempt (e.g. GLFW without a display)
MuJoCo 4.0 aborts the interpreter on the next one.
"""

from __future__ import annotations

import os

import mujoco

_failure: str | None = None


def new_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    global _failure
    if _failure is not None:
        raise RuntimeError(f"MuJoCo renderer unavailable in this process ({_failure})")
    try:
        return mujoco.Renderer(model, height, width)
    except Exception as e:
        _failure = f"{type(e).__name__}: {e}"
        raise


def renderer_available() -> bool:
    """Whether `mujoco.Renderer` works in this process (tries at most once after a failure)."""
    from mjx_push import scene

    try:
        new_renderer(scene.build_model("box"), 8, 8).close()
    except Exception:
        return False
    return True


def unavailable_reason() -> str:
    """Why rendering fails here, and what to do (for error messages)."""
    backend = os.environ.get("MUJOCO_GL", "the default (GLFW)")
    return (
        f"MuJoCo's offscreen renderer is unavailable ({_failure or 'not tried'}; MUJOCO_GL={backend}); "
        "on a machine without a display install EGL (libegl1, Mesa) and set MUJOCO_GL=egl before Python "
        "imports mujoco"
    )

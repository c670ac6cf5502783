"""export: trained policies outside JAX, on CPU MuJoCo and on a real robot.

- `policy_file`: one `.npz` of float32 weights + a JSON metadata record (`export_policy`, `load_npz`).
- `numpy_policy`: `NumpyPolicy`, the exported policy in plain NumPy (no JAX); `torch_policy`: the same as
  an optional torch `nn.Module`.
- `cpu_env`: the task on CPU MuJoCo (`CpuPushEnv`), running the MJX environment's own maths with NumPy
  (`mjx_push.control_law`, `mjx_push.mask_geometry`, `mjx_push.task_rules`) on MuJoCo's data
  (`controller_np`: the law on `MjData`; `corrections_np`: the counters as Python scalars); `gym_env`: it
  as the Gymnasium goal environment "MjxPush-v0" (registered by importing this package).
- `camera`: the real camera's image -> mask pipeline; `deploy`: the robot / camera / policy interfaces and
  the deployment loop, with a simulated robot and camera.
- `sim_eval` and `metrics`: the evaluation protocol (docs/task.md section 7) in CPU MuJoCo; `cli`: the
  `mjx-push export` and `mjx-push deploy` commands. See docs/deploy.md.

Importing this package imports neither JAX nor MuJoCo (a NumPy policy on a robot needs neither), and
the robot path (`deploy`, `numpy_policy`, `policy_file`, `camera`, `cpu_env`, `panda_py_robot`) imports
no JAX, flax, brax or MJX (tests/test_deploy_imports.py); only drawing random objects in `CpuPushEnv`
and exporting a trained policy import JAX, when called.
"""

import os as _os
import sys as _sys

import gymnasium as _gymnasium

# MuJoCo picks its OpenGL backend when first imported; on a Linux machine without a display the default
# (GLFW) cannot render, so choose EGL there unless the user chose (as `import mjx_push` does; repeated
# here because importing mjx_push would start JAX).
if _sys.platform.startswith("linux") and not _os.environ.get("DISPLAY") and "mujoco" not in _sys.modules:
    _os.environ.setdefault("MUJOCO_GL", "egl")

ENV_ID = "MjxPush-v0"


def register_envs() -> None:
    """Register the Gymnasium id "MjxPush-v0" (idempotent; done on import). `gymnasium.make` then returns
    the environment itself: Gymnasium's checker and order-enforcing wrappers would hide `compute_reward`
    from code that calls it on the returned object (SB3's `check_env`), and the environment enforces the
    call order and its 50-step time limit itself."""
    if ENV_ID not in _gymnasium.registry:
        _gymnasium.register(
            id=ENV_ID,
            entry_point="mjx_push.export.gym_env:MjxPushGymEnv",
            disable_env_checker=True,
            order_enforce=False,
        )


register_envs()

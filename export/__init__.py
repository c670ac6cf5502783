"""export: trained policies outside JAX, on CPU MuJoCo and on a real robot (issue 5).

- `policy_file`: one `.npz` of float32 weights + a JSON metadata record (`export_policy`, `load_npz`).
- `numpy_policy`: `NumpyPolicy`, the exported policy in plain NumPy (no JAX); `torch_policy`: the same as
  an optional torch `nn.Module`.
- `cpu_env`: the task on CPU MuJoCo (`CpuPushEnv`), with NumPy ports of the controller (`controller_np`),
  the masks (`masks_np`) and the correction counters (`corrections_np`); `gym_env`: it as the Gymnasium
  goal environment "MjxPush-v0".
- `camera`: the real camera's image -> mask pipeline; `deploy`: the robot / camera / policy interfaces and
  the deployment loop, with a simulated robot and camera.
- `sim_eval` and `metrics`: the SPEC section 7 protocol in CPU MuJoCo; `cli`: the `mjx-push export` and
  `mjx-push deploy` commands. See export/DEPLOY.md.
"""

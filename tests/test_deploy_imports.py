"""The robot path imports no JAX: the NumPy policy, the CPU MuJoCo environment, the camera pipeline, the
deployment loop and the task maths they share with MJX (`mjx_push.config`, `task_rules`, `control_law`,
`mask_geometry`) are imported and used in a fresh interpreter in which JAX, jaxlib, flax, optax, orbax,
brax and mujoco.mjx cannot be imported. Any attempt to import one fails the test, even one caught by a
`try`, and the message names the module that made it."""

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BLOCKED = ("jax", "jaxlib", "flax", "optax", "orbax", "brax", "mujoco.mjx")
DEPLOY_MODULES = (
    "export",
    "mjx_push.export.deploy",
    "mjx_push.export.numpy_policy",
    "mjx_push.export.policy_file",
    "mjx_push.export.pretrained",
    "mjx_push.export.camera",
    "mjx_push.export.cpu_env",
    "mjx_push.export.controller_np",
    "mjx_push.export.corrections_np",
    "mjx_push.export.panda_py_robot",
    "mjx_push.config",
    "mjx_push.task_rules",
    "mjx_push.control_law",
    "mjx_push.mask_geometry",
    "mjx_push.perturb",
)

# Installed first thing in the child: a meta-path finder that refuses the blocked packages and records
# every attempt with the innermost frame of this repository that made it.
_BLOCKER = """
import importlib.abc, json, sys, traceback

BLOCKED = {blocked!r}
ATTEMPTS = []


class Blocker(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if not any(name == b or name.startswith(b + ".") for b in BLOCKED):
            return None
        ours = [f for f in traceback.extract_stack()[:-1] if f.filename.startswith({repo!r}) and "site-packages" not in f.filename]
        where = f"{{ours[-1].filename}}:{{ours[-1].lineno}}" if ours else "?"
        ATTEMPTS.append(f"{{name}} (from {{where}})")
        raise ModuleNotFoundError(f"{{name}} is blocked: the deploy path must not import it", name=name)


sys.meta_path.insert(0, Blocker())


def report():
    loaded = sorted(m for m in sys.modules if any(m == b or m.startswith(b + ".") for b in BLOCKED))
    print("RESULT " + json.dumps({{"attempts": ATTEMPTS, "loaded": loaded}}))
"""

# The deploy path at work, NumPy only: every shipped policy acts on a zero observation, an analytic mask,
# the controller law on plain arrays (a robot's use), the deployment loop on the CPU simulator with a
# given object and a camera that shows the simulator's mask in the blue the default pipeline keeps.
_USE = """
import importlib

import numpy as np

for name in {modules!r}:
    importlib.import_module(name)

from mjx_push.export import camera, cpu_env, deploy, numpy_policy, pretrained
from mjx_push import config, control_law, mask_geometry, scene

n = scene.IMAGE_SIZE
zero = np.zeros((n, n), bool)
policies = pretrained.available()
assert policies, "no shipped policies"
for path in policies.values():
    policy = numpy_policy.NumpyPolicy.from_file(path)
    policy.reset()
    a_x, a_y, substeps = policy.act(zero, zero, np.zeros(2))
    assert -1 <= a_x <= 1 and -1 <= a_y <= 1 and isinstance(substeps, int) and 10 <= substeps <= 600

mask = mask_geometry.object_mask("box", [0.03, 0.02, 0.025], scene.CAMERA_POS[:2], 0.3, scene.TABLE_TOP + 0.025)
assert mask.shape == (n, n) and mask.any()

dq = control_law.law(
    np.zeros(3), np.array([0.0, 0.0, -1.0]), np.eye(3, 6), np.eye(3, 6), scene.HOME_QPOS, np.array([0.01, 0.0, 0.0]),
    config.ControllerConfig(),
)
assert dq.shape == (7,) and np.all(np.isfinite(dq))

home = scene.home_flange_pos()
params = config.ObjectParams(
    size=np.array([0.04, 0.03, 0.025]),
    mass=np.array(0.2),
    inertia=np.array([1.9e-4, 3.7e-4, 4.2e-4]),
    friction=np.array([0.5, 0.005, scene.OBJECT_ROLL_FRICTION]),
    start=np.array([home[0] + 0.1, home[1] + 0.08, 0.0]),
    goal=np.array([home[0] + 0.05, home[1] - 0.05, 0.0]),
)
env = cpu_env.CpuPushEnv(geom_type="box", mask_source="analytic", seed=0)
env.reset(params=params)


class MaskCamera:
    def frame(self):
        rgb = np.zeros((n, n, 3), np.uint8)
        rgb[env.object_mask(), 2] = 255
        return rgb


record = deploy.run_episode(policy, deploy.SimRobot(env), MaskCamera(), camera.MaskPipeline(), env.goal_mask, steps=2)
assert record["steps"] == 2 and np.array_equal(record["object_masks"][-1], env.object_mask())
report()
"""


def _run_blocked(body: str) -> tuple[subprocess.CompletedProcess, dict | None]:
    code = _BLOCKER.format(blocked=BLOCKED, repo=str(REPO)) + body
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    lines = [line for line in r.stdout.splitlines() if line.startswith("RESULT ")]
    return r, json.loads(lines[-1][len("RESULT ") :]) if lines else None


def test_deploy_path_imports_no_jax():
    r, result = _run_blocked(_USE.format(modules=DEPLOY_MODULES))
    assert r.returncode == 0 and result is not None, r.stdout[-2000:] + r.stderr[-4000:]
    assert result == {"attempts": [], "loaded": []}, result


def test_the_blocker_catches_an_import_of_jax():
    """The check has teeth: an import of jax, even one a `try` swallows, is caught and located."""
    body = "try:\n    import jax  # noqa\nexcept ImportError:\n    pass\nreport()\n"
    r, result = _run_blocked(body)
    assert r.returncode == 0 and result is not None, r.stderr[-4000:]
    assert result["loaded"] == [] and [a.split(" ")[0] for a in result["attempts"]] == ["jax"], result

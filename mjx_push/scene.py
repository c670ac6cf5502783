"""The pushing scene as MJCF, built in code from primitives (docs/task.md section 1).

One builder serves both simulators: `build_xml(shape)` returns the MJCF text, `build_model(shape)`
the compiled `mujoco.MjModel` (CPU MuJoCo), and `mjx_push.env` puts the same model on device.

The object's geom type is fixed per model (MJX cannot change a geom's type per environment), so there
is one model per shape: "box" or "cylinder". Sizes, mass, inertia and friction are placeholders that
`mjx_push.objects` overwrites per environment.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import mujoco
import numpy as np
from mjx_push.errors import ConfigError

SHAPES = ("box", "cylinder")

# --- Robot (Franka Emika Panda, Franka convention) ---------------------------------------------------
HOME_QPOS = np.array([0.0, -0.4476, 0.0, -2.117, 0.0, 1.665, 0.0])
JOINT_RANGE = np.array(
    [
        [-2.8973, 2.8973],
        [-1.7628, 1.7628],
        [-2.8973, 2.8973],
        [-3.0718, -0.0698],
        [-2.8973, 2.8973],
        [-0.0175, 3.7525],
        [-2.8973, 2.8973],
    ]
)
VELOCITY_LIMIT = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])
KV = np.array([30.0, 30.0, 30.0, 30.0, 10.0, 10.0, 5.0])
JOINT_DAMPING = 0.003

# Body frames: (pos in parent, quat in parent). A quaternion (1, +-1, 0, 0)/sqrt2 turns +-90 deg about x.
_S = np.sqrt(0.5)
_LINK_FRAMES = [
    ((0.0, 0.0, 0.333), (1.0, 0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (_S, -_S, 0.0, 0.0)),
    ((0.0, -0.316, 0.0), (_S, _S, 0.0, 0.0)),
    ((0.0825, 0.0, 0.0), (_S, _S, 0.0, 0.0)),
    ((-0.0825, 0.384, 0.0), (_S, -_S, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (_S, _S, 0.0, 0.0)),
    ((0.088, 0.0, 0.0), (_S, _S, 0.0, 0.0)),
]
FLANGE_OFFSET = 0.107

# Published Franka dynamic-identification values: mass, centre of mass, full inertia
# (ixx, iyy, izz, ixy, ixz, iyz) in the link frame.
_LINK_INERTIA = [
    (
        4.970684,
        (3.875e-03, 2.081e-03, -4.762e-02),
        (7.0337e-01, 7.0661e-01, 9.117e-03, -1.39e-04, 6.772e-03, 1.9169e-02),
    ),
    (
        0.646926,
        (-3.141e-03, -2.872e-02, 3.495e-03),
        (7.962e-03, 2.811e-02, 2.5995e-02, -3.925e-03, 1.0254e-02, 7.04e-04),
    ),
    (
        3.228604,
        (2.7518e-02, 3.9252e-02, -6.6502e-02),
        (3.7242e-02, 3.6155e-02, 1.083e-02, -4.761e-03, -1.1396e-02, -1.2805e-02),
    ),
    (
        3.587895,
        (-5.317e-02, 1.04419e-01, 2.7454e-02),
        (2.5853e-02, 1.9552e-02, 2.8323e-02, 7.796e-03, -1.332e-03, 8.641e-03),
    ),
    (
        1.225946,
        (-1.1953e-02, 4.1065e-02, -3.8437e-02),
        (3.5549e-02, 2.9474e-02, 8.627e-03, -2.117e-03, -4.037e-03, 2.29e-04),
    ),
    (
        1.666555,
        (6.0149e-02, -1.4117e-02, -1.0517e-02),
        (1.964e-03, 4.354e-03, 5.433e-03, 1.09e-04, -1.158e-03, 3.41e-04),
    ),
    (
        0.735522,
        (1.0517e-02, -4.252e-03, 6.1597e-02),
        (1.2516e-02, 1.0027e-02, 4.815e-03, -4.28e-04, -1.196e-03, -7.41e-04),
    ),
]

# Visual-only link capsules (fromto in the link frame) so renders look like an arm.
_LINK_VISUALS = [
    ((0, 0, -0.19), (0, 0, 0.0), 0.06),
    ((0, 0, 0), (0, -0.19, 0), 0.06),
    ((0, 0, -0.12), (0, 0, 0), 0.06),
    ((0, 0, 0), (-0.08, 0.1, 0), 0.055),
    ((0, 0, -0.22), (0, 0.06, -0.05), 0.05),
    ((0, 0, 0), (0.088, 0, 0), 0.045),
    ((0, 0, 0), (0, 0, 0.1), 0.04),
]

# --- End effector -------------------------------------------------------------------------------------
MOUNT_RADIUS, MOUNT_THICK, MOUNT_MASS = 0.0675, 0.015, 0.25
ROD_RADIUS, ROD_LENGTH, ROD_MASS = 0.0075, 0.155, 0.25
ROD_FRICTION = 1.0

# --- Table and world ----------------------------------------------------------------------------------
TABLE_TOP = 0.40
TABLE_X = (0.175, 0.875)
TABLE_Y = (-0.45, 0.45)
# Table coefficients sit at or below every object coefficient we accept, so MuJoCo's max rule makes
# the object-table contact use the object's sampled sliding friction.
TABLE_FRICTION = (0.01, 0.0005, 0.00005)
MIN_OBJECT_FRICTION = TABLE_FRICTION[0]

# --- Camera (under the glass table, looking straight up) ------------------------------------------------
CAMERA_POS = np.array([0.4, 0.0, -0.1])
CAMERA_FOVY = 65.0
IMAGE_SIZE = 64
OBJECT_RGBA = (0.0, 0.0, 1.0, 1.0)

# --- Object -------------------------------------------------------------------------------------------
OBJECT_ROLL_FRICTION = 0.0001
OBJECT_DAMPING = 0.01


@dataclass(frozen=True)
class SolverSettings:
    """MJX solver settings. Defaults chosen for speed; `tests/test_physics.py` checks that they keep the
    scene stable (docs/task.md section 8)."""

    iterations: int = 6
    ls_iterations: int = 6
    integrator: str = "implicitfast"  # treats the velocity servos' damping implicitly: stable at kv*dt/I near 1
    solver: str = "Newton"

    def __post_init__(self):
        if self.iterations < 1:
            raise ConfigError(f"solver.iterations must be >= 1, got {self.iterations}")
        if self.ls_iterations < 1:
            raise ConfigError(f"solver.ls_iterations must be >= 1, got {self.ls_iterations}")
        if self.integrator not in ("Euler", "implicitfast"):
            raise ConfigError(f"solver.integrator must be 'Euler' or 'implicitfast', got {self.integrator!r}")
        if self.solver not in ("Newton", "CG"):
            raise ConfigError(f"solver.solver must be 'Newton' or 'CG', got {self.solver!r}")


def _v(x) -> str:
    return " ".join(f"{float(a):.9g}" for a in x)


def _camera_xml() -> str:
    # Looking along world +z means the camera's -z axis points up. xyaxes gives the camera x axis
    # (image right) = world +x and y axis (image up) = world -y, so image rows grow with world +y.
    return (
        f'<camera name="under_table" pos="{_v(CAMERA_POS)}" xyaxes="1 0 0 0 -1 0" fovy="{CAMERA_FOVY}"/>'
        '<camera name="top" pos="0.5 0 1.6" xyaxes="0 -1 0 1 0 0" fovy="45"/>'
    )


def _arm_xml() -> str:
    # Only the rod collides (with the object and the table); every other robot geom is visual.
    vis = 'contype="0" conaffinity="0" group="2" rgba="0.92 0.92 0.95 1"'
    out = []
    for i, ((pos, quat), (mass, com, inertia), (a, b, r)) in enumerate(
        zip(_LINK_FRAMES, _LINK_INERTIA, _LINK_VISUALS), start=1
    ):
        lo, hi = JOINT_RANGE[i - 1]
        out.append(f'<body name="link{i}" pos="{_v(pos)}" quat="{_v(quat)}" gravcomp="1">')
        out.append(f'<inertial pos="{_v(com)}" mass="{mass}" fullinertia="{_v(inertia)}"/>')
        out.append(f'<joint name="joint{i}" axis="0 0 1" range="{lo} {hi}" damping="{JOINT_DAMPING}"/>')
        out.append(f'<geom type="capsule" fromto="{_v(a)} {_v(b)}" size="{r}" {vis}/>')
    # End effector on link 7: flange site, quick-mount disc, push rod.
    f = FLANGE_OFFSET
    out.append(f'<site name="flange" pos="0 0 {f}" size="0.01" group="4"/>')
    out.append(
        f'<body name="mount" pos="0 0 {f + MOUNT_THICK / 2}" gravcomp="1">'
        f'<geom name="mount" type="cylinder" size="{MOUNT_RADIUS} {MOUNT_THICK / 2}" mass="{MOUNT_MASS}" {vis}/>'
        "</body>"
    )
    # The rod spans 0.015..0.170 below the flange. It collides as a capsule of the same radius and
    # the same overall length (MJX has no cylinder-box collision).
    rod_mid = f + MOUNT_THICK + ROD_LENGTH / 2
    half = ROD_LENGTH / 2 - ROD_RADIUS
    out.append(
        f'<body name="rod" pos="0 0 {rod_mid}" gravcomp="1">'
        f'<geom name="rod" type="capsule" size="{ROD_RADIUS} {half}" mass="{ROD_MASS}" '
        f'friction="{ROD_FRICTION} 0.005 0.0001" contype="1" conaffinity="2" group="1" rgba="0.3 0.3 0.3 1"/>'
        f'<site name="rod_tip" pos="0 0 {ROD_LENGTH / 2}" size="0.005" group="4"/>'
        "</body>"
    )
    out.append("</body>" * 7)
    return "\n".join(out)


def _object_xml(shape: str) -> str:
    # Placeholder size and mass: overwritten per environment by mjx_push.objects.
    if shape == "box":
        geom = 'type="box" size="0.04 0.04 0.03"'
    else:
        geom = 'type="cylinder" size="0.045 0.03"'
    x, y = 0.45, 0.0
    return (
        f'<body name="object" pos="{x} {y} {TABLE_TOP + 0.03}">'
        f'<joint name="object" type="free" damping="{OBJECT_DAMPING}"/>'
        f'<geom name="object" {geom} mass="0.2" friction="0.5 0.005 {OBJECT_ROLL_FRICTION}" '
        'contype="2" conaffinity="1" material="object"/>'
        "</body>"
    )


def build_xml(shape: str, solver: SolverSettings = SolverSettings()) -> str:
    """MJCF text of the scene with an object of `shape` ("box" or "cylinder")."""
    if shape not in SHAPES:
        raise ConfigError(f"shape must be one of {SHAPES}, got {shape!r}")
    tx0, tx1 = TABLE_X
    ty0, ty1 = TABLE_Y
    table_center = ((tx0 + tx1) / 2, (ty0 + ty1) / 2, TABLE_TOP - 0.02)
    table_half = ((tx1 - tx0) / 2, (ty1 - ty0) / 2, 0.02)
    # Collision bits (a pair collides if contype of one & conaffinity of the other): rod (1, 2),
    # object (2, 1), table plane (1, 3): rod-object, object-table and rod-table, nothing else. Every
    # other geom has (0, 0); MJX 3.x does not filter static-static pairs, so the visual table box
    # never collides at all.
    # The table collides as a plane at its top surface: contact with the top face is the same as a box's,
    # and a plane pair is far cheaper in MJX than box-box; leaving the footprint is detected as
    # out-of-bounds by the environment (the object would fall off a real table there).
    return f"""
<mujoco model="mjx_push_{shape}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.001" gravity="0 0 -9.81" cone="elliptic" integrator="{solver.integrator}"
          solver="{solver.solver}" iterations="{solver.iterations}" ls_iterations="{solver.ls_iterations}">
  </option>
  <default>
    <geom condim="3"/>
  </default>
  <visual>
    <global offwidth="640" offheight="480"/>
    <quality offsamples="0"/>
    <headlight ambient="0.5 0.5 0.5" diffuse="0.4 0.4 0.4"/>
  </visual>
  <asset>
    <material name="object" rgba="{_v(OBJECT_RGBA)}" emission="1"/>
    <material name="glass" rgba="0.6 0.8 0.9 0.0"/>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.2 0.3 0.4" rgb2="0.1 0.2 0.3" width="64" height="64"/>
    <material name="floor" texture="grid" texrepeat="8 8"/>
  </asset>
  <worldbody>
    <light pos="0.5 0 2.0" dir="0 0 -1" directional="true"/>
    {_camera_xml()}
    <geom name="table_surface" type="plane" pos="0.525 0 {TABLE_TOP}" size="0.35 0.45 0.01"
          friction="{_v(TABLE_FRICTION)}" contype="1" conaffinity="3" group="3" rgba="0 0 0 0"/>
    <geom name="table_glass" type="box" pos="{_v(table_center)}" size="{_v(table_half)}"
          contype="0" conaffinity="0" group="3" material="glass"/>
    <body name="link0" pos="0 0 0">
      <geom type="cylinder" size="0.06 0.05" pos="0 0 0.05" contype="0" conaffinity="0" group="2" rgba="0.92 0.92 0.95 1"/>
      {_arm_xml()}
    </body>
    {_object_xml(shape)}
  </worldbody>
  <actuator>
    {"".join(f'<velocity name="v{i + 1}" joint="joint{i + 1}" kv="{KV[i]}" ctrlrange="{-VELOCITY_LIMIT[i]} {VELOCITY_LIMIT[i]}"/>' for i in range(7))}
  </actuator>
</mujoco>
"""


def build_model(shape: str, solver: SolverSettings = SolverSettings()) -> mujoco.MjModel:
    """Compiled scene (a fresh model on every call: callers may edit it)."""
    return mujoco.MjModel.from_xml_string(build_xml(shape, solver))


@dataclass(frozen=True)
class SceneIds:
    """Ids and addresses resolved once per model."""

    flange_site: int
    link7_body: int
    object_body: int
    object_geom: int
    rod_geom: int
    table_geom: int
    object_qpos: int  # start of the object's freejoint qpos (7: xyz + quat wxyz)
    object_qvel: int  # start of the object's freejoint qvel (6)


def scene_ids(m: mujoco.MjModel) -> SceneIds:
    obj_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
    obj_joint = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "object")
    return SceneIds(
        flange_site=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "flange"),
        link7_body=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "link7"),
        object_body=obj_body,
        object_geom=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object"),
        rod_geom=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "rod"),
        table_geom=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table_surface"),
        object_qpos=int(m.jnt_qposadr[obj_joint]),
        object_qvel=int(m.jnt_dofadr[obj_joint]),
    )


@functools.lru_cache(maxsize=None)
def home_flange_pos() -> np.ndarray:
    """Flange position at the home configuration (computed once with CPU MuJoCo)."""
    m = build_model("box")
    d = mujoco.MjData(m)
    d.qpos[:7] = HOME_QPOS
    mujoco.mj_kinematics(m, d)
    return d.site_xpos[scene_ids(m).flange_site].copy()

"""A sketch of `mjx_push.export.deploy.Robot` on a real Franka Panda with panda-py (not installed by mjx-push, and
never run here: check the API names against your panda-py version before trusting it with an arm).

It runs the simulator's own task-space velocity law (`mjx_push.control_law.law`, with NumPy) at 1 kHz
in panda-py's `IntegratedVelocity` joint-velocity controller, so the real flange follows targets as the
simulated one does. panda-py is imported only when a robot is made, so this module imports (and CI
checks that it still fits the `Robot` interface) without it.

    robot = PandaPyRobot("172.16.0.2")
    result = mjx_push.export.deploy.run_episode(policy, robot, camera, pipeline, goal_mask)
"""

from __future__ import annotations

import numpy as np

from mjx_push.control_law import law
from mjx_push.config import ControllerConfig
from mjx_push.scene import HOME_QPOS


class PandaPyRobot:
    def __init__(self, host: str, cfg: ControllerConfig = ControllerConfig(safety_scale=0.5)):
        import panda_py
        from panda_py import controllers, libfranka

        self._controllers, self._frame = controllers, libfranka.Frame.kFlange
        self.panda, self.cfg = panda_py.Panda(host), cfg
        self.model = self.panda.get_model()
        self.home()

    def _flange(self, state):
        """Flange pose (4x4) and Jacobian (6x7) in the base frame, independent of Desk's EE frame."""
        T = np.asarray(self.model.pose(self._frame, state)).reshape(4, 4, order="F")
        J = np.asarray(self.model.zero_jacobian(self._frame, state)).reshape(6, 7, order="F")
        return T, J

    def flange_xy(self) -> np.ndarray:
        return self._flange(self.panda.get_state())[0][:2, 3]

    def move_to(self, xyz) -> None:
        self.target = np.asarray(xyz, dtype=float)

    def wait_ms(self, n: int) -> None:
        with self.panda.create_context(frequency=1000, max_runtime=n / 1000) as ctx:
            while ctx.ok():
                s = self.panda.get_state()
                T, J = self._flange(s)
                dq = law(T[:3, 3], T[:3, 2], J[:3, :6], J[3:, :6], np.asarray(s.q), self.target, self.cfg)
                self.ctrl.set_control(dq)
        self.ctrl.set_control(np.zeros(7))

    def home(self) -> None:
        self.panda.move_to_joint_position(HOME_QPOS)  # stops any running controller
        self.ctrl = self._controllers.IntegratedVelocity()
        self.panda.start_controller(self.ctrl)
        self.target = self._flange(self.panda.get_state())[0][:3, 3]

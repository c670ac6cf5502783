"""Gymnasium goal environment over `export.cpu_env.CpuPushEnv`, registered as "MjxPush-v0".

    import export.gym_env, gymnasium
    env = gymnasium.make("MjxPush-v0", geom_type="box", mask_source="analytic")

Observation layout (a flat `Dict`, which Stable-Baselines3's `MultiInputPolicy` and HER accept; SB3 does
not support nested Dicts):
- "observation": Box(float32, (2 + 64*64,)): the noisy flange xy in metres, then the object mask
  flattened row-major as 0.0 / 1.0 (`split_observation` undoes it);
- "achieved_goal": Box(uint8, (64*64,)) in {0, 1}: the object mask, flattened row-major;
- "desired_goal": Box(uint8, (64*64,)) in {0, 1}: the goal mask (the object at the goal pose).
Masks follow `mjx_push.masks`' pixel convention. Action space: Box(-1, 1, (3,), float32) =
(a_x, a_y, a_s), exactly as the MJX environment; non-finite components become 0 (counted in
info["bad_actions"]), a wrong shape raises ValueError.

Rewards come from ground truth, never from the masks (as in the reference): -1 while the object's centre
is at least tau = 0.01 from the goal's, else 0. `compute_reward` therefore reads the positions from
`info` ("object_xy", "goal_xy"), for one transition or a batch (an array or list of info dicts, as SB3's
HER passes them, or one dict of stacked arrays). A learner that relabels goals must relabel
info["goal_xy"] with the chosen future step's info["object_xy"] as well (SPEC section 6): SB3's stock
`HerReplayBuffer` replaces only desired_goal and passes the transition's own info, so with it the
relabelled rewards would still refer to the original goal.

Episodes are exactly `EnvConfig.episode_length` (50) steps: `truncated` at the end, never `terminated`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from export.cpu_env import CAMERAS, MAX_RENDER_SIZE, CpuPushEnv
from mjx_push import scene
from mjx_push.env import EnvConfig

ENV_ID = "MjxPush-v0"
N_PIX = scene.IMAGE_SIZE * scene.IMAGE_SIZE
EE_BOUND = 1.0  # |flange x|, |flange y| < 1 m: the Panda's reach is 0.855 m


def split_observation(observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """"observation" vector(s) (..., 2 + 4096) -> (ee_xy (..., 2), object_mask (..., 64, 64) bool)."""
    observation = np.asarray(observation)
    n = scene.IMAGE_SIZE
    return observation[..., :2], observation[..., 2:].reshape(observation.shape[:-1] + (n, n)) > 0.5


class MjxPushGymEnv(gymnasium.Env):
    """Goal-conditioned Gymnasium view of the CPU MuJoCo pushing task. Keyword arguments go to
    `CpuPushEnv`; `render_mode="rgb_array"` makes `render()` return the "top" camera at `render_size`."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, config: EnvConfig | None = None, geom_type: str | None = None, mask_source: str = "auto",
                 render_mode: str | None = None, render_size: tuple[int, int] = (240, 320),
                 render_camera: str = "top"):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.sim = CpuPushEnv(config or EnvConfig(), geom_type=geom_type, mask_source=mask_source)
        self.config = self.sim.config
        self.render_mode = render_mode
        self.render_size = tuple(render_size)
        self.render_camera = render_camera
        if not (len(self.render_size) == 2 and 1 <= self.render_size[0] <= MAX_RENDER_SIZE[0]
                and 1 <= self.render_size[1] <= MAX_RENDER_SIZE[1]):
            raise ValueError(f"render_size must be (height, width) within {MAX_RENDER_SIZE}, got {render_size!r}")
        if render_camera not in CAMERAS:
            raise ValueError(f"render_camera must be one of {CAMERAS}, got {render_camera!r}")
        low = np.concatenate([np.full(2, -EE_BOUND), np.zeros(N_PIX)]).astype(np.float32)
        high = np.concatenate([np.full(2, EE_BOUND), np.ones(N_PIX)]).astype(np.float32)
        goal = spaces.Box(0, 1, (N_PIX,), np.uint8)
        self.observation_space = spaces.Dict(
            {"observation": spaces.Box(low, high, dtype=np.float32), "achieved_goal": goal, "desired_goal": goal}
        )
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """`options` may hold "params" (an `ObjectParams`) and "geom_type" to fix the episode's object."""
        super().reset(seed=seed)
        options = options or {}
        unknown = set(options) - {"params", "geom_type"}
        if unknown:
            raise ValueError(f"options accepts 'params' and 'geom_type', got {sorted(unknown)}")
        self.sim.np_random = self.np_random  # one generator: gymnasium's seeding drives every draw
        obs = self.sim.reset(params=options.get("params"), geom_type=options.get("geom_type"))
        return self._obs(obs), self._info(self.sim.info())

    def step(self, action):
        obs, _, terminated, truncated, info = self.sim.step(action)
        out, info = self._obs(obs), self._info(info)
        reward = float(self.compute_reward(out["achieved_goal"], out["desired_goal"], info))
        return out, reward, terminated, truncated, info

    def compute_reward(self, achieved_goal, desired_goal, info) -> np.ndarray | float:
        """Sparse reward from the ground truth carried in `info`: 0 if ||object_xy - goal_xy|| < tau else -1.
        `info` is one dict (arrays (2,) or stacked (B, 2)) or a sequence / object array of B dicts. The
        masks only fix the batch shape. Returns float32 of shape achieved_goal.shape[:-1]."""
        batch_shape = np.shape(achieved_goal)[:-1]
        obj, goal = _ground_truth(info)
        if obj.shape[:-1] != batch_shape and obj.shape[:-1] != (int(np.prod(batch_shape)),):
            raise ValueError(f"info holds {obj.shape[:-1]} transitions but achieved_goal {batch_shape}")
        dist = np.linalg.norm(obj - goal, axis=-1).reshape(batch_shape)
        return (dist < self.config.success_tau).astype(np.float32) - 1.0

    def render(self):
        if self.render_mode == "rgb_array":
            return self.sim.render_rgb(self.render_camera, self.render_size)
        return None

    def close(self):
        self.sim.close()

    # --- helpers -------------------------------------------------------------------------------------
    @staticmethod
    def _obs(obs: dict) -> dict:
        mask = obs["object_mask"].reshape(-1)
        return {
            "observation": np.concatenate([obs["ee_xy"], mask]).astype(np.float32),
            "achieved_goal": mask.astype(np.uint8),
            "desired_goal": obs["goal_mask"].reshape(-1).astype(np.uint8),
        }

    @staticmethod
    def _info(info: dict) -> dict:
        info = dict(info)
        info["is_success"] = bool(info["success"])  # the key SB3's loggers read
        return info


def _ground_truth(info: Any) -> tuple[np.ndarray, np.ndarray]:
    """(object_xy (..., 2), goal_xy (..., 2)) from one info dict or a sequence of them."""
    if isinstance(info, Mapping):
        return np.asarray(info["object_xy"], np.float64), np.asarray(info["goal_xy"], np.float64)
    if isinstance(info, (Sequence, np.ndarray)):
        infos = list(np.asarray(info, dtype=object).reshape(-1))
        if not all(isinstance(i, Mapping) for i in infos):
            raise ValueError("info must be a dict or a sequence of dicts with 'object_xy' and 'goal_xy'")
        return (np.stack([np.asarray(i["object_xy"], np.float64) for i in infos]),
                np.stack([np.asarray(i["goal_xy"], np.float64) for i in infos]))
    raise ValueError(f"info must be a dict or a sequence of dicts, got {type(info).__name__}")


def _register() -> None:
    # Guarded: importing this module twice (or reloading it) must not re-register the id.
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="export.gym_env:MjxPushGymEnv")


_register()

__all__ = ["ENV_ID", "MjxPushGymEnv", "split_observation"]

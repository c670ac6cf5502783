"""Gymnasium goal environment over `mjx_push.export.cpu_env.CpuPushEnv`, registered as "MjxPush-v0".

    import mjx_push.export, gymnasium                # importing export registers the id
    env = gymnasium.make("MjxPush-v0")      # or gymnasium.make("export:MjxPush-v0") without the import

Goal representation (the goal-environment convention of Gymnasium-Robotics and Stable-Baselines3):
- "achieved_goal": Box(float32, (2,)): the object's centre xy in metres (ground truth);
- "desired_goal": Box(float32, (2,)): the goal's centre xy in metres;
- "observation": what the robot sees, by `observation`:
  - "latent" (default): Box(float32, (8,)) = [flange xy (noisy), z_obj], z_obj the 6-number encoder
    latent of the object mask (the shipped encoder, or `encoder=PATH`);
  - "mask": Box(float32, (2 + 64*64,)) = [flange xy, the object mask flattened row-major as 0.0 / 1.0]
    (`split_observation` undoes it).

Why the goals are positions: the task's reward is a function of the true object and goal positions
(-1 while they are at least tau = 0.01 apart, else 0), and hindsight relabelling (SB3's
`HerReplayBuffer`) replaces only `desired_goal` and recomputes the reward as
`compute_reward(achieved_goal, desired_goal, info)` with an empty info by default. So the reward must be
a function of the two goal entries alone, and those must hold the positions: masks or latents locate
the object only to about a pixel (1 cm), the size of the success radius itself. The goal image is not
part of "observation" either, since a relabelled transition would keep the old goal there. The cost:
an SB3 policy, which reads every key, sees the true object and goal positions, information the paper's
vision agents (and mjx-push's JAX learner, which relabels the latent and the true goal together) do
not get.

Action space: Box(-1, 1, (3,), float32) = (a_x, a_y, a_s), exactly as the MJX environment (a_s is the
raw action, not a substep count); non-finite components become 0 (counted in info["bad_actions"]),
components outside [-1, 1] are clipped with a warning, a wrong shape raises ValueError. Episodes are
exactly `EnvConfig.episode_length` steps: `truncated` at the end, never `terminated`.

Masks come from the rendered under-table camera by default (`mask_source="render"`, needing MuJoCo's
offscreen renderer: `import export` selects EGL on a Linux machine without a display); "analytic" uses
the projection MJX trains with; "auto" renders when it can and warns when it cannot.

`gymnasium.make` returns the environment itself (see `mjx_push.export.register_envs`).
"""

from __future__ import annotations

import functools
from pathlib import Path

import gymnasium
import numpy as np
from gymnasium import spaces

from mjx_push.export import ENV_ID
from mjx_push.export.cpu_env import CAMERAS, MAX_RENDER_SIZE, CpuPushEnv
from mjx_push import scene
from mjx_push.config import EnvConfig
from mjx_push.errors import ConfigError

N_PIX = scene.IMAGE_SIZE * scene.IMAGE_SIZE
EE_BOUND = 1.0  # |flange x|, |flange y| < 1 m: the Panda's reach is 0.855 m
OBSERVATIONS = ("latent", "mask")
LATENT_DIM = 6
# Box bound of the latent entries: the shipped encoder's latents of task masks lie within +-3 (even an
# all-ones mask gives 11); infinite bounds would make Gymnasium's checker warn.
LATENT_BOUND = 100.0


def split_observation(observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ "mask" observation vector(s) (..., 2 + 4096) -> (ee_xy (..., 2), object_mask (..., 64, 64) bool)."""
    observation = np.asarray(observation)
    n = scene.IMAGE_SIZE
    if observation.shape[-1] != 2 + N_PIX:
        raise ConfigError(f"expected 'mask' observations of length {2 + N_PIX}, got {observation.shape[-1]}")
    return observation[..., :2], observation[..., 2:].reshape(observation.shape[:-1] + (n, n)) > 0.5


@functools.lru_cache(maxsize=4)
def _encoder(path: str | None):
    """(jitted encode, params) for the encoder at `path` (None: the shipped one), shared by instances."""
    import jax

    from mjx_push import encoder as enc

    return jax.jit(enc.encode), enc.load(Path(path) if path else None)


class MjxPushGymEnv(gymnasium.Env):
    """Goal-conditioned Gymnasium view of the CPU MuJoCo pushing task. `config`, `geom_type` and
    `mask_source` go to `CpuPushEnv`; `render_mode="rgb_array"` makes `render()` return `render_camera`
    at `render_size` (height, width)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        config: EnvConfig | None = None,
        geom_type: str | None = None,
        mask_source: str = "render",
        observation: str = "latent",
        encoder: str | Path | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (240, 320),
        render_camera: str = "top",
    ):
        if observation not in OBSERVATIONS:
            raise ConfigError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.render_size = tuple(render_size)
        if not (
            len(self.render_size) == 2
            and 1 <= self.render_size[0] <= MAX_RENDER_SIZE[0]
            and 1 <= self.render_size[1] <= MAX_RENDER_SIZE[1]
        ):
            raise ConfigError(f"render_size must be (height, width) within {MAX_RENDER_SIZE}, got {render_size!r}")
        if render_camera not in CAMERAS:
            raise ConfigError(f"render_camera must be one of {CAMERAS}, got {render_camera!r}")
        if encoder is not None and not Path(encoder).is_file():
            raise ConfigError(f"encoder: no such file {encoder}")
        self.sim = CpuPushEnv(config or EnvConfig(), geom_type=geom_type, mask_source=mask_source)
        self.config = self.sim.config
        self.observation_mode = observation
        self.render_mode = render_mode
        self.render_camera = render_camera
        self._encode = _encoder(str(encoder) if encoder is not None else None) if observation == "latent" else None
        if observation == "latent":
            low = np.concatenate([np.full(2, -EE_BOUND), np.full(LATENT_DIM, -LATENT_BOUND)]).astype(np.float32)
            high = -low
        else:
            low = np.concatenate([np.full(2, -EE_BOUND), np.zeros(N_PIX)]).astype(np.float32)
            high = np.concatenate([np.full(2, EE_BOUND), np.ones(N_PIX)]).astype(np.float32)
        # Goals lie on the table (an object leaving its footprint is an invalid state and is put back).
        goal = spaces.Box(
            np.array([scene.TABLE_X[0], scene.TABLE_Y[0]], np.float32),
            np.array([scene.TABLE_X[1], scene.TABLE_Y[1]], np.float32),
            dtype=np.float32,
        )
        self.observation_space = spaces.Dict(
            {"observation": spaces.Box(low, high, dtype=np.float32), "achieved_goal": goal, "desired_goal": goal}
        )
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)

    @property
    def mask_source(self) -> str:
        """The masks in use: "render" or "analytic" ("auto" resolved)."""
        return self.sim.mask_source_used

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """`options` may hold "params" (an `ObjectParams`) and "geom_type" to fix the episode's object."""
        super().reset(seed=seed)
        options = options or {}
        unknown = set(options) - {"params", "geom_type"}
        if unknown:
            raise ConfigError(f"options accepts 'params' and 'geom_type', got {sorted(unknown)}")
        self.sim.np_random = self.np_random  # one generator: gymnasium's seeding drives every draw
        obs = self.sim.reset(params=options.get("params"), geom_type=options.get("geom_type"))
        out = self._obs(obs)
        return out, self._info(self.sim.info(), out)

    def step(self, action):
        obs, _, terminated, truncated, info = self.sim.step(action)
        out = self._obs(obs)
        info = self._info(info, out)
        return (
            out,
            float(self.compute_reward(out["achieved_goal"], out["desired_goal"], info)),
            terminated,
            truncated,
            info,
        )

    def compute_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        """Sparse reward from the goals alone: 0 where ||achieved_goal - desired_goal|| < tau, else -1.
        Goals are xy positions (..., 2); any leading batch shape; `info` is ignored (may be None, a dict
        or a list of dicts, as SB3's HER passes it). Returns float32 of the batch shape."""
        ag = np.asarray(achieved_goal, np.float64)
        dg = np.asarray(desired_goal, np.float64)
        if ag.shape[-1:] != (2,) or dg.shape[-1:] != (2,):
            raise ConfigError(f"goals are xy positions of shape (..., 2), got {ag.shape} and {dg.shape}")
        dist = np.linalg.norm(ag - dg, axis=-1)
        return (dist < self.config.success_tau).astype(np.float32) - np.float32(1.0)

    def render(self):
        if self.render_mode == "rgb_array":
            return self.sim.render_rgb(self.render_camera, self.render_size)
        return None

    def close(self):
        self.sim.close()

    # --- helpers -------------------------------------------------------------------------------------
    def _obs(self, obs: dict) -> dict:
        ee = np.asarray(obs["ee_xy"], np.float32)
        if self._encode is not None:
            fn, params = self._encode
            seen = np.asarray(fn(params, obs["object_mask"]), np.float32)
        else:
            seen = obs["object_mask"].reshape(-1).astype(np.float32)
        info = self.sim.info()
        return {
            "observation": np.concatenate([ee, seen]).astype(np.float32),
            "achieved_goal": np.asarray(info["object_xy"], np.float32),
            "desired_goal": np.asarray(info["goal_xy"], np.float32),
        }

    def _info(self, info: dict, obs: dict) -> dict:
        info = dict(info)
        # The key SB3's loggers read, consistent with the reward (both from the float32 goals).
        info["is_success"] = bool(self.compute_reward(obs["achieved_goal"], obs["desired_goal"]) == 0.0)
        return info


__all__ = ["ENV_ID", "MjxPushGymEnv", "split_observation"]

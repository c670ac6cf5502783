"""The pushing task for brax's trainers (`brax.training.agents.ppo`, `sac`) and brax's training wrappers.

`PushEnv` is the simulation's own functional environment: dict observations with 64x64 masks, `done`
set by its own step counter at the time limit, and everything about an episode (object, goal,
counters) in `info`. brax's training wrappers (`brax.envs.training.wrap`: vmap, `EpisodeWrapper`,
`AutoResetWrapper`) assume otherwise: `EpisodeWrapper` counts steps and sets `done` and `truncation`
itself, and `AutoResetWrapper` resets an environment by swapping in the `pipeline_state` and `obs` it
saved at the first reset, leaving `info` alone. Under them `PushEnv` would end an episode at every step
after the first episode, report time limits as terminations, carry its counters over, and replay one
object per environment forever; brax's SAC also rejects dict observations.

`BraxPushEnv` wraps one `PushEnv` so that brax's pipeline works as brax users expect:

- flat observations (`observation_size` is an int): "latent" (default) [flange xy, z_obj, z_goal], the
  paper's 14 numbers with the mask encoder run on device; "state" [flange xy, object xy, cos/sin object
  yaw, goal xy, cos/sin goal yaw] (10, ground truth); "mask" [flange xy, object mask, goal mask] (8194);
- time limits belong to the wrapper: `done` is never set at the end of an episode, so `EpisodeWrapper`
  marks it as a truncation (PPO and SAC leave the step out of their value targets), and
  `info["time_out"]` marks it for PPO's `bootstrap_on_timeout=True`. Pass
  `episode_length=env.episode_length` (50) to brax's `train`. `done` = 1, a termination, only when the
  simulation breaks (NaN, object through or off the table), so that episode ends at once;
- the whole episode (the inner `PushEnv` state with its object, goal and counters) is the
  `pipeline_state`, which `AutoResetWrapper` swaps; and every step stages a fresh episode (new object,
  start and goal, from the environment's own key) in `info["first_pipeline_state"]` / `["first_obs"]`,
  the slots `AutoResetWrapper` resets from, so each episode has a new object;
- metrics "success" (1 at steps within tau of the goal) and "distance" (object-goal distance, m), which
  `EpisodeWrapper` sums over an episode; rewards are the task's sparse ones by default, or the negative
  object-goal distance in metres with `reward="dense"`.

One `BraxPushEnv` simulates one object shape ("box" or "cylinder"): MJX fixes a geom's type when the
step is compiled, and brax vmaps a single environment.

Compatibility: brax 0.14.2's trainers (PPO, SAC) call `jax.device_put_replicated`, which jax 0.10
removed (it raises AttributeError there). Importing this module puts back an equivalent built on the
public `jax.device_put` (the replacement jax's pmap migration guide gives), only if jax lacks one.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State

from mjx_push import encoder as enc
from mjx_push import scene
from mjx_push.env import EnvConfig, PushEnv
from mjx_push.errors import ConfigError

OBSERVATIONS = ("latent", "state", "mask")
REWARDS = ("sparse", "dense")
_NEXT_EPISODE = 0x7E5E7  # folded into the environment's key to draw the episode staged for auto-reset


def _device_put_replicated(x, devices):
    """`x` (a pytree) stacked once per device along a new leading axis, one slice on each device."""
    mesh = jax.sharding.Mesh(np.array(devices), ("devices",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("devices"))
    return jax.device_put(jax.tree.map(lambda a: jnp.stack([jnp.asarray(a)] * len(devices)), x), sharding)


if not hasattr(jax, "device_put_replicated"):  # jax >= 0.10: brax's trainers still call it
    jax.device_put_replicated = _device_put_replicated


class BraxPushEnv(Env):
    def __init__(
        self,
        config: EnvConfig = EnvConfig(),
        geom_type: str = "box",
        observation: str = "latent",
        reward: str = "sparse",
        encoder_params=None,
    ):
        if observation not in OBSERVATIONS:
            raise ConfigError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
        if reward not in REWARDS:
            raise ConfigError(f"reward must be one of {REWARDS}, got {reward!r}")
        self.env = PushEnv(config, geom_type)
        self.config = config
        self.observation = observation
        self.reward_mode = reward
        self.episode_length = config.episode_length
        if observation == "latent" and encoder_params is None:
            encoder_params = enc.load()  # the shipped encoder
        self.encoder_params = encoder_params

    # --- brax Env interface -------------------------------------------------------------------------
    @property
    def observation_size(self) -> int:
        n = scene.IMAGE_SIZE * scene.IMAGE_SIZE
        return {"latent": 2 + 2 * enc.LATENT_DIM, "state": 10, "mask": 2 + 2 * n}[self.observation]

    @property
    def action_size(self) -> int:
        return 3

    @property
    def backend(self) -> str:
        return "mjx"

    def reset(self, rng: jax.Array) -> State:
        inner = self._start(rng)
        zero = jnp.zeros((), jnp.float32)
        return State(
            pipeline_state=inner,
            obs=self._obs(inner),
            reward=zero,
            done=zero,
            metrics=self._metrics(inner),
            info={"time_out": zero},
        )

    def step(self, state: State, action: jax.Array) -> State:
        prev = state.pipeline_state
        inner = self.env.step(prev, action)
        broken = inner.info["invalid_count"] > prev.info["invalid_count"]
        info = dict(state.info)
        # brax's PPO with bootstrap_on_timeout reads it: the episode's time limit (this environment's
        # episode_length, which brax's episode_length must equal) ends it, not a termination.
        info["time_out"] = ((inner.info["step"] >= self.episode_length) & ~broken).astype(jnp.float32)
        if "first_pipeline_state" in info:  # under brax's AutoResetWrapper: stage the next episode
            fresh = self._start(jax.random.fold_in(inner.info["rng"], _NEXT_EPISODE))
            info["first_pipeline_state"] = fresh
            info["first_obs"] = self._obs(fresh)
        metrics = dict(state.metrics)  # keeps what wrappers added (brax's EvalWrapper: "reward")
        metrics.update(self._metrics(inner))
        return state.replace(
            pipeline_state=inner,
            obs=self._obs(inner),
            reward=self._reward(inner),
            done=broken.astype(jnp.float32),
            metrics=metrics,
            info=info,
        )

    # --- helpers -------------------------------------------------------------------------------------
    def _start(self, rng: jax.Array) -> State:
        inner = self.env.reset(rng)
        if self.observation == "latent":  # the goal's latent, once per episode (kept through PushEnv's steps)
            info = dict(inner.info)
            info["z_goal"] = enc.encode(self.encoder_params, info["goal_mask"])
            inner = inner.replace(info=info)
        return inner

    def _distance(self, inner: State) -> jax.Array:
        return jnp.linalg.norm(inner.info["object_xy"] - inner.info["goal_xy"])

    def _reward(self, inner: State) -> jax.Array:
        return inner.reward if self.reward_mode == "sparse" else -self._distance(inner)

    def _metrics(self, inner: State) -> dict:
        return {"success": inner.metrics["success"], "distance": self._distance(inner)}

    def _obs(self, inner: State) -> jax.Array:
        ee = inner.obs["ee_xy"]
        if self.observation == "latent":
            parts = [ee, enc.encode(self.encoder_params, inner.obs["object_mask"]), inner.info["z_goal"]]
        elif self.observation == "state":
            i = inner.info
            parts = [
                ee,
                i["object_xy"],
                jnp.cos(i["object_yaw"])[None],
                jnp.sin(i["object_yaw"])[None],
                i["goal_xy"],
                jnp.cos(i["goal_yaw"])[None],
                jnp.sin(i["goal_yaw"])[None],
            ]
        else:
            parts = [ee, inner.obs["object_mask"].reshape(-1), inner.obs["goal_mask"].reshape(-1)]
        return jnp.concatenate([jnp.asarray(p, jnp.float32) for p in parts])

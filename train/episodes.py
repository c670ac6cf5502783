"""The evaluation protocol's episodes (docs/task.md section 7): `EvalSpec` names a set of test episodes
(setting, shape filter, count, seed) and `episode_objects` draws them. Episode i's object, start and goal
come from fold_in(PRNGKey(seed), i) alone, so every agent, the in-run evaluations of training and both
simulators meet the same episodes.

Settings: "standard" (Table I), "difficult" (the paper's figure: mass U[0.001, 0.01], sliding friction
U[0.2, 0.3], minimum full height 0.052), or "custom" with the ranges given. Shapes: "cylinder",
"square", "rectangular", "cuboid", or "all" (the episode index decides: even -> cuboid, odd ->
cylinder, so the split is exact and independent of the batch size).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from mjx_push import objects, scene
from mjx_push.errors import ConfigError

SETTINGS = ("standard", "difficult", "custom")
SHAPES = ("all", "cylinder", "square", "rectangular", "cuboid")
DIFFICULT = dict(mass=(0.001, 0.01), friction=(0.2, 0.3), min_height=0.052)


@dataclasses.dataclass(frozen=True)
class EvalSpec:
    setting: str = "difficult"
    shape: str = "all"
    episodes: int = 100
    seed: int = 1_000_003  # distinct from training seeds; shared by every agent
    batch: int = 20  # episodes simulated in parallel (does not change the episodes)
    mass: tuple[float, float] | None = None  # custom setting: ranges replacing Table I's
    friction: tuple[float, float] | None = None
    min_height: float | None = None
    record: int = 0  # keep the per-step trajectories of the first `record` episodes (for videos)
    success_tau: float | None = None  # success radius (m) to score at; None: the one the policy trained for

    def __post_init__(self):
        if self.setting not in SETTINGS:
            raise ConfigError(f"setting must be one of {SETTINGS}, got {self.setting!r}")
        if self.shape not in SHAPES:
            raise ConfigError(f"shape must be one of {SHAPES}, got {self.shape!r}")
        if not (isinstance(self.episodes, int) and self.episodes > 0):
            raise ConfigError(f"episodes must be a positive integer, got {self.episodes!r}")
        if not (isinstance(self.batch, int) and self.batch > 0):
            raise ConfigError(f"batch must be a positive integer, got {self.batch!r}")
        custom = any(v is not None for v in (self.mass, self.friction, self.min_height))
        if custom and self.setting != "custom":
            raise ConfigError("mass / friction / min_height ranges need setting 'custom'")
        if not 0 <= self.record <= self.episodes:
            raise ConfigError(f"record must be in [0, episodes], got {self.record}")
        if self.success_tau is not None and not (math.isfinite(self.success_tau) and self.success_tau > 0):
            raise ConfigError(f"success_tau must be a positive number of metres, got {self.success_tau!r}")

    def object_config(self, base: objects.ObjectConfig | None = None) -> objects.ObjectConfig:
        """The object distribution; uniform sampling whatever the agent trained on."""
        cfg = dataclasses.replace(base or objects.ObjectConfig(), mode="uniform")
        if self.setting == "difficult":
            cfg = dataclasses.replace(cfg, **DIFFICULT)
        elif self.setting == "custom":
            fields = {
                k: v
                for k, v in (("mass", self.mass), ("friction", self.friction), ("min_height", self.min_height))
                if v is not None
            }
            cfg = dataclasses.replace(cfg, **fields)
        return cfg


def episode_geom_type(shape: str, i: int) -> str:
    """The geom type of episode `i` under shape filter `shape` ("all": even cuboids, odd cylinders)."""
    if shape == "all":
        return ("box", "cylinder")[i % 2]
    return "cylinder" if shape == "cylinder" else "box"


def episode_objects(spec: EvalSpec, base: objects.ObjectConfig, geom_type: str, indices: np.ndarray):
    """(ObjectParams, environment keys) of episodes `indices` (all of `geom_type`): episode i's object,
    start and goal are drawn from fold_in(PRNGKey(spec.seed), i) alone, so every policy and both
    simulators (MJX here, CPU MuJoCo in `mjx-push deploy`) meet the same episodes."""
    cfg = dataclasses.replace(spec.object_config(base), shape=_filter(spec.shape, geom_type))
    home = jnp.asarray(scene.home_flange_pos()[:2], jnp.float32)
    base_key = jax.random.PRNGKey(spec.seed)
    keys = jax.vmap(lambda i: jax.random.fold_in(base_key, i))(jnp.asarray(indices))
    k_obj = jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys)
    k_env = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    params = jax.vmap(lambda k: objects.sample(k, cfg, geom_type, home))(k_obj)
    return params, k_env


def geom_types(shape: str) -> tuple[str, ...]:
    return {"all": ("box", "cylinder"), "cylinder": ("cylinder",)}.get(shape, ("box",))


def _filter(shape: str, geom_type: str) -> str:
    if shape == "all":
        return "cuboid" if geom_type == "box" else "cylinder"
    return shape

"""Running mean and variance of the networks' inputs, and how they reach the networks.

The statistics (``RunningStats`` per input group: count, mean and summed squared deviations, merged
batch by batch with Chan et al.'s parallel formula) live in the training state. After every batch of
episodes the learner merges that batch's valid steps in and writes mean and std into the "norm"
collection of the actor's, the critics' and the target critics' variables (see
``mjx_push.train.networks.Normalizer``), so the networks standardise their inputs with the latest figures and a
saved actor carries the figures it was trained with.

Groups: ``ee_xy`` (flange xy) and ``z`` (mask latents: the object's and the goal's codes share one
distribution, since HER's goals are achieved codes); for the privileged critic ``priv`` (the ground
truth state) and ``goal`` (the object xy of every step, which is what relabelled goals are).
"""

from __future__ import annotations

import flax.struct
import jax
import jax.numpy as jnp

from mjx_push.train.networks import ACTOR_NORM_GROUPS, NORM_MIN_STD, critic_norm_groups


@flax.struct.dataclass
class RunningStats:
    count: jax.Array  # float32 number of samples
    mean: jax.Array  # [D]
    m2: jax.Array  # [D] sum of squared deviations from the mean

    @classmethod
    def zeros(cls, dim: int) -> "RunningStats":
        return cls(jnp.zeros((), jnp.float32), jnp.zeros((dim,), jnp.float32), jnp.zeros((dim,), jnp.float32))

    @property
    def std(self) -> jax.Array:
        var = self.m2 / jnp.maximum(self.count, 1.0)
        return jnp.maximum(jnp.sqrt(var), NORM_MIN_STD)

    def update(self, x: jax.Array, weight: jax.Array) -> "RunningStats":
        """Merge samples ``x [..., D]`` with ``weight [...]`` in {0, 1} (0: ignore the sample)."""
        x = x.reshape(-1, x.shape[-1])
        w = weight.reshape(-1).astype(jnp.float32)
        n_b = jnp.sum(w)
        mean_b = jnp.sum(x * w[:, None], 0) / jnp.maximum(n_b, 1.0)
        m2_b = jnp.sum(w[:, None] * (x - mean_b) ** 2, 0)
        n = self.count + n_b
        delta = mean_b - self.mean
        mean = self.mean + delta * n_b / jnp.maximum(n, 1.0)
        m2 = self.m2 + m2_b + delta**2 * self.count * n_b / jnp.maximum(n, 1.0)
        return RunningStats(n, mean, m2)


def groups_from_episodes(episodes: dict, critic_obs: str) -> dict[str, tuple[jax.Array, jax.Array]]:
    """(samples, weights) per group from a batch of episode records (invalid episodes weigh 0)."""
    steps = jnp.broadcast_to(episodes["valid"][:, None], episodes["ee_xy"].shape[:2])
    out = {"ee_xy": (episodes["ee_xy"], steps), "z": (episodes["z_obj"], steps)}
    if critic_obs == "privileged":
        out["priv"] = (episodes["priv"], steps)
        out["goal"] = (episodes["obj_xy"], steps)
    return out


def init_stats(critic_obs: str, priv_dim: int) -> dict[str, RunningStats]:
    """Empty statistics of every group the actor and the critics standardise."""
    groups = {**ACTOR_NORM_GROUPS, **critic_norm_groups(critic_obs, priv_dim)}
    return {name: RunningStats.zeros(dim) for name, dim in groups.items()}


def update_stats(stats: dict[str, RunningStats], episodes: dict, critic_obs: str) -> dict[str, RunningStats]:
    new = groups_from_episodes(episodes, critic_obs)
    return {name: s.update(*new[name]) for name, s in stats.items()}


def write(variables, stats: dict[str, RunningStats]):
    """``variables`` with every "norm" entry ``<group>_mean`` / ``<group>_std`` set from ``stats``
    (broadcast over leading axes such as the twin critics'); variables without "norm" pass through."""
    if "norm" not in variables:
        return variables

    def put(path, leaf):
        name = path[-1].key
        group, _, what = name.rpartition("_")
        if group not in stats:
            return leaf
        value = stats[group].mean if what == "mean" else stats[group].std
        return jnp.broadcast_to(value, leaf.shape).astype(leaf.dtype)

    return {**variables, "norm": jax.tree_util.tree_map_with_path(put, variables["norm"])}

"""On-device ring buffer of whole episodes with HER "future" relabelling (docs/task.md section 6).

The buffer keeps whole episodes rather than transitions because the GRU agents need the full history
up to t (and t+1) recomputed with the relabelled goal. Each slot holds one episode of T steps:

    z_obj  [T+1, 6]  latent object code; index 0 is the reset observation
    ee_xy  [T+1, 2]  end-effector xy
    obj_xy [T+1, 2]  ground-truth object xy (never observed; only for rewards and relabelling)
    z_goal [6]       latent goal code
    goal_xy [2]      ground-truth goal xy
    action [T, 3]
    valid  bool      False for empty slots and for episodes the simulator flagged (NaN, out of bounds)
    demo   bool      the episode was the scripted expert's (a demonstration)
    priv   [T+1, P]  ground-truth state for a privileged critic (only when P > 0); priv[:, :2] is the
                     object's xy
    expert_action [T, 3]  what the scripted expert would have done at each step (noise-free; only when
                     the learner stores expert labels for behaviour cloning)

Slots are written at ``count % capacity`` (a scatter, never a roll of the whole buffer). Invalid
slots have zero sampling weight, so they are never sampled.
"""

from __future__ import annotations

import flax.struct
import jax
import jax.numpy as jnp

from mjx_push import task_rules
from mjx_push.train.config import ReplayConfig
from mjx_push.errors import ConfigError

Episodes = dict  # name -> array with a leading episode axis, fields as in the module docstring


@flax.struct.dataclass
class ReplayBuffer:
    data: Episodes  # every leaf has a leading [capacity] axis
    count: jax.Array  # int32: episodes ever added; the next write goes to slot count % capacity
    success_tau: float = flax.struct.field(pytree_node=False)  # the task's success radius (its rewards)
    her_k: int = flax.struct.field(pytree_node=False, default=4)

    @property
    def capacity(self) -> int:
        return self.data["valid"].shape[0]

    @property
    def episode_len(self) -> int:
        return self.data["action"].shape[1]


def episode_spec(
    episode_len: int, action_dim: int = 3, priv_dim: int = 0, expert_labels: bool = False
) -> dict[str, tuple[tuple[int, ...], jnp.dtype]]:
    """Shape (without the episode axis) and dtype of each field of an episode record."""
    T = episode_len
    spec = {
        "z_obj": ((T + 1, 6), jnp.float32),
        "ee_xy": ((T + 1, 2), jnp.float32),
        "obj_xy": ((T + 1, 2), jnp.float32),
        "z_goal": ((6,), jnp.float32),
        "goal_xy": ((2,), jnp.float32),
        "action": ((T, action_dim), jnp.float32),
        "valid": ((), jnp.bool_),
        "demo": ((), jnp.bool_),
    }
    if priv_dim:
        spec["priv"] = ((T + 1, priv_dim), jnp.float32)
    if expert_labels:
        spec["expert_action"] = ((T, action_dim), jnp.float32)
    return spec


def init(
    config: ReplayConfig,
    episode_len: int,
    action_dim: int = 3,
    priv_dim: int = 0,
    expert_labels: bool = False,
    *,
    success_tau: float,
) -> ReplayBuffer:
    """An empty buffer of episodes of ``episode_len`` steps of a task of success radius ``success_tau``
    (both the environment's: ``make_train`` reads them from its adapter)."""
    capacity = config.capacity_transitions // episode_len
    if capacity < 1:
        raise ConfigError(
            f"replay.capacity_transitions must hold at least one episode of {episode_len} steps, "
            f"got {config.capacity_transitions}"
        )
    spec = episode_spec(episode_len, action_dim, priv_dim, expert_labels)
    data = {k: jnp.zeros((capacity,) + shape, dtype) for k, (shape, dtype) in spec.items()}
    return ReplayBuffer(data=data, count=jnp.zeros((), jnp.int32), her_k=config.her_k, success_tau=success_tau)


def add(buffer: ReplayBuffer, episodes: Episodes) -> ReplayBuffer:
    """Write a batch of n episodes (leading axis n <= capacity) to the next n slots, modulo capacity."""
    n = episodes["valid"].shape[0]
    if n > buffer.capacity:
        raise ConfigError(f"cannot add {n} episodes at once to a buffer of {buffer.capacity} episodes")
    if set(episodes) - {"demo"} != set(buffer.data) - {"demo"}:  # "demo" is optional: False when absent
        raise ConfigError(f"episode fields {sorted(episodes)} differ from the buffer's {sorted(buffer.data)}")
    slots = (buffer.count + jnp.arange(n, dtype=jnp.int32)) % buffer.capacity
    valid = episodes["valid"].astype(bool)

    def write(store, new):
        new = new.astype(store.dtype)
        # Zero the records of invalid episodes: they are never sampled, and this keeps NaNs or huge
        # values from out-of-bounds simulations out of device memory that later gathers touch.
        keep = valid.reshape((n,) + (1,) * (new.ndim - 1))
        return store.at[slots].set(jnp.where(keep, new, jnp.zeros_like(new)))

    data = {k: write(buffer.data[k], episodes[k]) for k in buffer.data if k not in ("valid", "demo")}
    data["valid"] = buffer.data["valid"].at[slots].set(valid)
    demo = episodes.get("demo", jnp.zeros((n,), bool))
    data["demo"] = buffer.data["demo"].at[slots].set(jnp.asarray(demo).astype(bool))
    return buffer.replace(data=data, count=buffer.count + n)


def num_valid_episodes(buffer: ReplayBuffer) -> jax.Array:
    return jnp.sum(buffer.data["valid"].astype(jnp.int32))


def num_valid_transitions(buffer: ReplayBuffer) -> jax.Array:
    return num_valid_episodes(buffer) * buffer.episode_len


def sparse_reward(obj_xy: jax.Array, goal_xy: jax.Array, success_tau: float) -> jax.Array:
    """-1 while the object is at least ``success_tau`` from the goal, else 0."""
    dist = jnp.linalg.norm(obj_xy - goal_xy, axis=-1)
    return task_rules.sparse_reward(dist, success_tau).astype(jnp.float32)


def drop_demos(buffer: ReplayBuffer, when) -> ReplayBuffer:
    """The buffer with its demonstration episodes marked invalid (never sampled again) where ``when``
    (a traced bool) holds; unchanged otherwise. Their slots are reused by later episodes as usual."""
    gone = buffer.data["demo"] & jnp.asarray(when)
    return buffer.replace(data={**buffer.data, "valid": buffer.data["valid"] & ~gone})


def num_demo_episodes(buffer: ReplayBuffer) -> jax.Array:
    return jnp.sum((buffer.data["valid"] & buffer.data["demo"]).astype(jnp.int32))


def sample(
    buffer: ReplayBuffer,
    key: jax.Array,
    batch_size: int,
    success_tau=None,
    demos_only: bool = False,
    relabel: bool = True,
) -> dict[str, jax.Array]:
    """Sample transitions (e, t) with HER "future" relabelling.

    ``success_tau`` (default the buffer's) is the radius of the recomputed rewards (a curriculum may
    change it during training). ``demos_only`` draws from the valid demonstration episodes only;
    ``relabel=False`` keeps every goal (behaviour-cloning batches: the expert's action is meant for
    the episode's own goal).

    e is uniform over the valid stored episodes and t ~ U{0..T-1}. With probability her_k/(her_k+1)
    the goal is replaced by what was achieved at obs index k ~ U{t+1..T} (SB3's "future" strategy over
    the transitions t..T-1, each contributing its next observation): both the latent goal
    ``z_obj[k]`` and the ground-truth goal ``obj_xy[k]``. The reward of (o_t, a_t, o_{t+1}) is
    recomputed from ``obj_xy[t+1]`` and the (new) ground-truth goal. There are no terminal flags:
    episodes end by time-limit truncation, so the learner always bootstraps.

    Returns whole episodes (``ee_xy``, ``z_obj``, ``obj_xy`` [B, T+1, .]) with the possibly relabelled
    ``z_goal [B, 6]`` / ``goal_xy [B, 2]``, plus ``t``, ``action`` (a_t), ``reward``, and for
    diagnostics ``episode`` (slot index), ``relabelled`` and ``goal_index`` (k, or -1).
    The caller must make sure the buffer holds at least one valid episode.
    """
    T = buffer.episode_len
    k_ep, k_t, k_her, k_future = jax.random.split(key, 4)

    # Uniform over valid slots, exactly: draw a rank r < n_valid and find the slot holding the r-th
    # valid episode by a search on the running count of valid slots (integer arithmetic, no weights).
    valid = buffer.data["valid"] & buffer.data["demo"] if demos_only else buffer.data["valid"]
    cum = jnp.cumsum(valid.astype(jnp.int32))
    rank = jax.random.randint(k_ep, (batch_size,), 0, jnp.maximum(cum[-1], 1))
    e = jnp.searchsorted(cum, rank, side="right").astype(jnp.int32)

    t = jax.random.randint(k_t, (batch_size,), 0, T)
    relabel_prob = buffer.her_k / (buffer.her_k + 1) if relabel else 0.0
    relabel = jax.random.uniform(k_her, (batch_size,)) < relabel_prob
    future = jax.random.randint(k_future, (batch_size,), t + 1, T + 1)

    ep = jax.tree.map(lambda x: x[e], buffer.data)
    rows = jnp.arange(batch_size)
    z_goal = jnp.where(relabel[:, None], ep["z_obj"][rows, future], ep["z_goal"])
    goal_xy = jnp.where(relabel[:, None], ep["obj_xy"][rows, future], ep["goal_xy"])
    tau = buffer.success_tau if success_tau is None else success_tau
    reward = sparse_reward(ep["obj_xy"][rows, t + 1], goal_xy, tau)
    extra = {"priv": ep["priv"]} if "priv" in ep else {}
    if "expert_action" in ep:
        extra["expert_action"] = ep["expert_action"][rows, t]
    return {
        **extra,
        "ee_xy": ep["ee_xy"],
        "z_obj": ep["z_obj"],
        "obj_xy": ep["obj_xy"],
        "z_goal": z_goal,
        "goal_xy": goal_xy,
        "t": t,
        "action": ep["action"][rows, t],
        "reward": reward,
        "episode": e,
        "relabelled": relabel,
        "goal_index": jnp.where(relabel, future, -1),
    }

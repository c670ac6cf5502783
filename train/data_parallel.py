"""Data-parallel training over the devices of every process, on JAX's own runtime.

With ``loop.data_parallel`` = D > 1, the trainer's pure functions (train/loop.py) are written for one
device's share of the run: ``num_envs / D`` environments, a replay shard of ``1 / D`` of the capacity,
``1 / D`` of every update's batch, each gradient averaged over the mesh axis ``AXIS``
(``mjx_push.train.sac.make_update``'s ``axis_name``). This module runs them with ``shard_map`` over a 1-D mesh
of D devices, which spans every process once ``jax.distributed`` is initialised (``initialize``), so
one program drives a laptop's host devices, a node of GPUs or a cluster alike.

The global layout of a ``TrainState``: every replay leaf gains a leading [D] axis split over the mesh
(each device holds its own shard; nothing of it is ever exchanged); everything else (parameters,
optimiser states, counters, the key, the best actor) is replicated, and stays identical on every
device because every device applies the same averaged step. Rollouts return their episodes split over
the mesh (they go straight into the learner on the device that collected them) and their per-episode
statistics gathered onto every device, as host numbers. Host inputs (flags, the expert mask, evaluation
episodes) are placed with ``put``, which every process calls with the same values.

A checkpoint of such a state is one orbax checkpoint that every process writes its shards of
(train/runs/run.py); the host side (logs, policies, the run directory) belongs to process 0.
"""

from __future__ import annotations

import os

import jax
import numpy as np
from jax.flatten_util import ravel_pytree
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

from mjx_push import xla
from mjx_push.errors import ConfigError

AXIS = "data"


def initialize(coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None):
    """Join a multi-process run (``jax.distributed.initialize``) before any computation. Arguments left
    None come from ``MJX_PUSH_COORDINATOR`` / ``MJX_PUSH_NUM_PROCESSES`` / ``MJX_PUSH_PROCESS_ID``.
    The coordinator ``auto`` leaves all three to JAX's detection of the cluster it runs in (SLURM, Open
    MPI, Kubernetes, ...). Nothing happens when none is given: one process."""
    coordinator = coordinator or os.environ.get("MJX_PUSH_COORDINATOR")
    if coordinator == "auto":
        if num_processes is not None or process_id is not None:
            raise ConfigError("--coordinator auto takes the process count and id from the cluster: drop them")
        jax.distributed.initialize()
        return
    env_int = lambda name: int(os.environ[name]) if os.environ.get(name) else None  # noqa: E731
    num_processes = num_processes if num_processes is not None else env_int("MJX_PUSH_NUM_PROCESSES")
    process_id = process_id if process_id is not None else env_int("MJX_PUSH_PROCESS_ID")
    if coordinator is None and num_processes is None and process_id is None:
        return
    if num_processes is not None and (num_processes < 1 or not 0 <= (process_id or 0) < num_processes):
        raise ConfigError(f"process id {process_id} is not one of {num_processes} processes")
    jax.distributed.initialize(coordinator, num_processes, process_id)


def is_primary() -> bool:
    """The process that owns the host side of a run (logs, policies, messages): process 0."""
    return jax.process_index() == 0


def make_mesh(num_devices: int) -> Mesh:
    """A 1-D mesh over the first ``num_devices`` devices of all processes (all of them when there are
    several processes, so every process takes part)."""
    devices = jax.devices()
    if num_devices > len(devices):
        raise ConfigError(
            f"loop.data_parallel is {num_devices} but this run has {len(devices)} device(s) over "
            f"{jax.process_count()} process(es); lower it, add processes, or on a CPU ask for host devices "
            "(mjx_push.xla.use_cpu_devices)"
        )
    if jax.process_count() > 1 and num_devices != len(devices):
        raise ConfigError(
            f"loop.data_parallel must use every device of a multi-process run ({len(devices)}), got {num_devices}"
        )
    return Mesh(np.array(devices[:num_devices]), (AXIS,))


def _is_spec(x) -> bool:
    return isinstance(x, P)


def state_specs(state):
    """Partition specs of a (global) TrainState: the replay buffer split over the mesh, the rest replicated."""
    specs = jax.tree.map(lambda _: P(), state)
    return specs.replace(buffer=jax.tree.map(lambda _: P(AXIS), state.buffer))


def shardings(mesh: Mesh, specs):
    return jax.tree.map(lambda s: NamedSharding(mesh, s), specs, is_leaf=_is_spec)


def put(tree, mesh: Mesh, specs):
    """Host values (every process passes the same) as global arrays laid out by ``specs`` (a spec or a
    tree of them, a prefix of ``tree``); arrays already spread over the mesh are left alone."""
    full = set(mesh.devices.flat)

    def one(x, spec):
        if isinstance(x, jax.Array) and x.sharding.device_set == full:
            return x
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, NamedSharding(mesh, spec), lambda index: x[index])

    if _is_spec(specs):
        return jax.tree.map(lambda x: one(x, specs), tree)
    return jax.tree.map(lambda s, sub: jax.tree.map(lambda x: one(x, s), sub), specs, tree, is_leaf=_is_spec)


def _local(ts):
    return ts.replace(buffer=jax.tree.map(lambda x: x[0], ts.buffer))


def _global(ts):
    return ts.replace(buffer=jax.tree.map(lambda x: x[None], ts.buffer))


def episode_specs(episodes: dict) -> dict:
    """Evaluation episodes: the ``use`` flag replicated, every per-environment field split."""
    return {k: P() if k == "use" else P(AXIS) for k in episodes}


class Sharded:
    """A trainer's ``init``, ``rollout``, ``learn`` and ``select`` over ``mesh`` (see the module)."""

    def __init__(self, trainer, mesh: Mesh):
        self.mesh = mesh
        smap = lambda f, i, o: jax.shard_map(f, mesh=mesh, in_specs=i, out_specs=o, check_vma=False)  # noqa: E731
        local_state = jax.eval_shape(trainer.init, jax.random.PRNGKey(0))
        self.specs = state_specs(local_state)
        self.state_shardings = shardings(mesh, self.specs)
        self._init = jax.jit(smap(lambda key: _global(trainer.init(key)), P(), self.specs))

        def learn(ts, episodes, key):
            ts, metrics = trainer.learn(_local(ts), episodes, key)
            return _global(ts), metrics

        self._learn = jax.jit(
            smap(learn, (self.specs, P(AXIS), P()), (self.specs, P())),
            donate_argnums=0,
            compiler_options=xla.physics_free_options(),
        )
        self._select = jax.jit(
            trainer.select, donate_argnums=0, out_shardings=(self.state_shardings, NamedSharding(mesh, P()))
        )

        def rollout(params, key, random_actions, deterministic, expert_envs, *episodes):
            eps, stats = trainer.rollout(params, key, random_actions, deterministic, expert_envs, *episodes)
            return eps, jax.lax.all_gather(stats, AXIS, tiled=True)

        self._rollouts: dict = {}  # compiled on first use, with and without evaluation episodes
        self._smap, self._rollout_fn = smap, rollout

    def init(self, key):
        return self._init(put(key, self.mesh, P()))

    def learn(self, ts, episodes, key):
        return self._learn(ts, episodes, put(key, self.mesh, P()))

    def select(self, ts, stats):
        return self._select(ts, put(stats, self.mesh, P()))

    def rollout(self, params, key, random_actions, deterministic, expert_envs, episodes=None):
        """-> (episodes split over the mesh, per-episode statistics as NumPy arrays in batch order)."""
        args = (params, key, random_actions, deterministic, expert_envs) + (() if episodes is None else (episodes,))
        specs = (P(), P(), P(), P(), P(AXIS)) + (() if episodes is None else (episode_specs(episodes),))
        if len(args) not in self._rollouts:  # with and without evaluation episodes
            self._rollouts[len(args)] = jax.jit(self._smap(self._rollout_fn, specs, (P(AXIS), P())))
        eps, stats = self._rollouts[len(args)](*(put(x, self.mesh, spec) for x, spec in zip(args, specs)))
        return eps, jax.device_get(stats)


def flat_pmean(tree, axis: str):
    """The mean of ``tree`` over the mapped ``axis`` in one all-reduce of one flat vector (across
    processes every collective is a round trip, so a pytree's leaves go together)."""
    flat, unravel = ravel_pytree(tree)
    return unravel(jax.lax.pmean(flat, axis))


def split_evenly(k: int, parts: int) -> list[int]:
    """``k`` items over ``parts`` devices: as even as possible, the first ones taking the remainder."""
    return [k // parts + (i < k % parts) for i in range(parts)]

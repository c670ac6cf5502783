"""A batch of pushing environments with mixed object shapes, stepped in one jitted function.

Why shape groups: MJX fixes each geom's type at trace time, and its collision driver runs every
candidate geom pair for every environment. Giving the object both a box and a cylinder geom (and
parking the unused one) would make every environment pay for both shapes' collisions and contact
rows: it compiles one substep program instead of two but runs every substep slower, which a run of more
than a few batches loses (`benchmarks/shape_programs.py`). Instead the batch is split into groups, one `PushEnv` (one compiled model) per geom type, each
vmapped over its own slice: every environment only runs the collisions of its own shape. With shape
filter "any" the first ceil(N/2) environments hold cuboids and the rest cylinders, so each shape has
probability 1/2 per environment slot as in the paper; "cylinder" / "cuboid" / "square" / "rectangular"
put all N in one group. Concatenated outputs (observations, rewards, info) list the box group first.

Devices: each group is split evenly over the backend's devices (`mjx_push.devices`; on a CPU the
host devices of `mjx_push.xla`, one per core), so the environments of one batch run on every core.
`max_devices=1` keeps the whole batch on one device.

Utilisation: in `step`, a vmapped `while_loop` runs until the slowest environment of its group has
spent its a_s substeps, the others standing still (masked). `utilisation(a_s)` gives the useful
fraction. `begin` / `advance` / `finish` / `ready` expose the three phases of `PushEnv`'s step per
environment, so a scheduler (train/loop.py) can advance fixed chunks of substeps and hand each
environment its next action as soon as its step is done.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import State
from flax import struct

from mjx_push import devices, objects, perturb
from mjx_push.env import EnvConfig, PushEnv
from mjx_push.errors import ConfigError


@struct.dataclass
class BatchState:
    groups: tuple[State, ...]  # one brax State per shape group, each with a leading batch axis

    @property
    def num_envs(self) -> int:
        return sum(g.reward.shape[0] for g in self.groups)

    def cat(self, get) -> jax.Array:
        """Concatenate `get(state)` over the groups along the batch axis."""
        return jax.tree.map(_join, *[get(g) for g in self.groups])

    @property
    def obs(self):
        return self.cat(lambda s: s.obs)

    @property
    def reward(self):
        return self.cat(lambda s: s.reward)

    @property
    def done(self):
        return self.cat(lambda s: s.done)

    # brax's State fields over the whole batch, read as there: `state.info["object_xy"]`. An entry is
    # concatenated when read (not the whole dict: the groups' MJX `initial_data` differ in structure).
    @property
    def info(self) -> Mapping[str, Any]:
        return _Concatenated(self, "info")

    @property
    def metrics(self) -> Mapping[str, Any]:
        return _Concatenated(self, "metrics")


def _join(*xs: jax.Array) -> jax.Array:
    """The groups' arrays concatenated along the batch axis. Read outside a trace, each join waits for
    its inputs and its result before the next is dispatched: the groups are spread over the host devices, so each
    eager join is a small program over all of them with a collective, and on CPU (jaxlib 0.10) a burst
    of such programs dispatched without waiting can leave the devices in different collectives until
    XLA aborts the process (`benchmarks/collective_burst.py`)."""
    if any(isinstance(x, jax.core.Tracer) for x in xs):
        return jnp.concatenate(xs, axis=0)
    jax.block_until_ready(xs)  # the step that made them may still run
    return jax.block_until_ready(jnp.concatenate(xs, axis=0))


class _Concatenated(Mapping):
    """A read-only view of one dict field of every group's State, each entry concatenated on reading."""

    def __init__(self, state: BatchState, field: str):
        self._state, self._field = state, field

    def __getitem__(self, key: str):
        return self._state.cat(lambda s: getattr(s, self._field)[key])

    def __iter__(self):
        return iter(getattr(self._state.groups[0], self._field))

    def __len__(self) -> int:
        return len(getattr(self._state.groups[0], self._field))


class PushBatch:
    """`num_envs` environments under `config`; `reset(key)` and `step(state, actions)` are pure and
    jittable (wrap them in `jax.jit` yourself, or use `jit_reset` / `jit_step`). Each shape group is
    split over up to `max_devices` devices (None: all of the default backend's). `shapes`, a part of
    the config's shape groups (`config.objects.shapes()`), builds only those: one group of a batch
    as a batch of its own, its environments drawn as that group's are (a program per group)."""

    def __init__(
        self,
        config: EnvConfig = EnvConfig(),
        num_envs: int = 8,
        max_devices: int | None = None,
        shapes: tuple[str, ...] | None = None,
    ):
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ConfigError(f"num_envs must be a positive integer, got {num_envs!r}")
        all_shapes = config.objects.shapes()
        if shapes is not None and (not shapes or tuple(s for s in all_shapes if s in shapes) != tuple(shapes)):
            raise ConfigError(
                f"shapes must be some of the shape filter {config.objects.shape!r}'s groups {all_shapes} "
                f"in their order, got {shapes!r}"
            )
        shapes = all_shapes if shapes is None else tuple(shapes)
        if len(shapes) == 2 and num_envs < 2:
            raise ConfigError("shape filter 'any' needs num_envs >= 2 (one group per shape); pick a shape or more envs")
        self.config = config
        self.num_envs = num_envs
        if len(shapes) == 2:
            counts = (num_envs - num_envs // 2, num_envs // 2)
        else:
            counts = (num_envs,)
        self.envs = tuple(PushEnv(config, s) for s in shapes)
        self.counts = counts
        self.shape_ids = jnp.concatenate(
            [jnp.full(n, i, jnp.int32) for i, n in enumerate(counts)]
        )  # index into self.geom_types, per environment
        self.geom_types = shapes
        self.mesh = devices.env_mesh(counts, max_devices)
        self.num_devices = 1 if self.mesh is None else self.mesh.size
        self.jit_reset = jax.jit(self.reset)
        self.jit_step = jax.jit(self.step)

    def reset(self, key: jax.Array, episodes: dict | None = None) -> BatchState:
        """New episodes, drawn from `key`; where `episodes["use"]` (a traced bool) is True, the given
        ones instead: `episodes["keys"]` [N, 2] and `episodes["params"]` (ObjectParams [N]), in the
        batch's order (box group first), as `PushEnv.reset_with` takes them (evaluation episodes
        through the same compiled reset as training's; they run without the environment's
        perturbations, as the evaluation protocol does). `key` may also be the environments' own keys
        [N, 2], those `jax.random.split(key, N)` would give them (a share of a larger batch)."""
        keys = key if jnp.ndim(key) == 2 else jax.random.split(key, self.num_envs)
        if episodes is None:
            return BatchState(tuple(self._run(env.reset, k) for env, k in zip(self.envs, self._split(keys))))
        use = jnp.broadcast_to(jnp.asarray(episodes["use"]), (self.num_envs,))

        def one(env):
            def f(k, u, k_given, p_given):
                rng, k_obj = jax.random.split(k)  # PushEnv.reset's draws
                drawn = objects.sample(k_obj, env.config.objects, env.geom_type, env.home_flange[:2])
                pick = lambda a, b: jnp.where(u, a, b)  # noqa: E731
                key, params = pick(k_given, rng), jax.tree.map(pick, p_given, drawn)
                if not env.perturbed:
                    return env.reset_with(key, params)
                # Given episodes (evaluations) run clean in a randomised environment.
                record = jax.tree.map(pick, perturb.neutral_episode(xp=jnp), env.draw_perturbation(key))
                return env.reset_with(key, params, record)

            return f

        parts = zip(
            self.envs,
            self._split(keys),
            self._split(use),
            self._split(episodes["keys"]),
            self._split_tree(episodes["params"]),
        )
        return BatchState(tuple(self._run(one(env), k, u, kg, pg) for env, k, u, kg, pg in parts))

    def step(self, state: BatchState, actions: jax.Array) -> BatchState:
        actions = jnp.asarray(actions)
        if actions.shape != (self.num_envs, 3):
            raise ConfigError(f"actions must have shape ({self.num_envs}, 3), got {actions.shape}")
        parts = self._split(actions)
        return BatchState(tuple(self._run(env.step, s, a) for env, s, a in zip(self.envs, state.groups, parts)))

    # --- the three phases, per environment (a scheduler's view of the batch) -----------------------
    def begin(self, state: BatchState, actions: jax.Array, mask: jax.Array) -> BatchState:
        """Start a new env step with `actions` in the environments where `mask` [N] is True."""
        actions = jnp.asarray(actions)
        if actions.shape != (self.num_envs, 3):
            raise ConfigError(f"actions must have shape ({self.num_envs}, 3), got {actions.shape}")
        return self._masked(lambda env, s, a: env.begin_step(s, a), state, mask, actions)

    def advance(self, state: BatchState, max_substeps: int) -> BatchState:
        """Run up to `max_substeps` substeps of every environment's current step (spent ones stand still)."""
        return BatchState(
            tuple(self._run(lambda s: env.advance(s, max_substeps), g) for env, g in zip(self.envs, state.groups))
        )

    def ready(self, state: BatchState) -> jax.Array:
        """[N] bool: the environment has spent its current step's substeps."""
        return state.info["substeps_left"] == 0

    def finish(self, state: BatchState, mask: jax.Array) -> BatchState:
        """Finish the current step (observation, reward, validity) where `mask` is True."""
        return self._masked(lambda env, s, _: env.finish_step(s), state, mask, jnp.zeros((self.num_envs,)))

    def _run(self, fn, *args):
        """`fn` of one environment, vmapped over a group's environments and split over the devices."""
        return devices.shard(jax.vmap(fn), self.mesh)(*args)

    def _masked(self, fn, state: BatchState, mask: jax.Array, per_env: jax.Array) -> BatchState:
        def one(env):  # per environment: the phase where masked, the old state elsewhere
            def f(s, m, x):
                return jax.tree.map(lambda n, o: jnp.where(m, n, o), fn(env, s, x), s)

            return f

        return BatchState(
            tuple(
                self._run(one(env), g, m, x)
                for env, g, m, x in zip(self.envs, state.groups, self._split(mask), self._split(per_env))
            )
        )

    def _split(self, x):
        out, i = [], 0
        for n in self.counts:
            out.append(x[i : i + n])
            i += n
        return out

    def _split_tree(self, tree):
        """`_split` of every leaf: one pytree per group."""
        leaves, treedef = jax.tree.flatten(tree)
        return [jax.tree.unflatten(treedef, parts) for parts in zip(*[self._split(x) for x in leaves])]

    def utilisation(self, substeps: jax.Array) -> jax.Array:
        """Fraction of executed substeps that were useful when the environments of each group ran
        `substeps` (N,) and every group waited for its slowest member."""
        parts = self._split(jnp.asarray(substeps))
        useful = sum(jnp.sum(p) for p in parts)
        executed = sum(jnp.max(p) * p.shape[0] for p in parts)
        return useful / executed

"""Jitted rollout + update loop (brax / purejaxrl style) and its host driver.

``make_train(config, adapter)`` returns pure, jittable pieces (the rollout split into a program per shape
group, ``Trainer.rollout_split == "groups"``, runs its jitted programs itself and is called unjitted):

* ``init(key) -> TrainState``
* ``rollout(actor_params, key, random_actions, deterministic, expert_envs, episodes) -> (episodes,
  stats)``: one whole episode in each of ``num_envs`` environments (``mjx_push.train.rollout.make_collect``).
  Evaluation reuses it chunk by chunk.
* ``learn(state, episodes, key)``: add the episodes to replay, then ``lax.scan`` over
  ``num_envs * episode_len * utd`` SAC updates (skipped until warm-up is over and replay holds at
  least ``batch_size`` valid transitions); ``split_keys`` derives the two keys from the state's.
* ``select(state, eval_stats)`` keeps the best actor params by mean evaluation reward (the reference's
  selection).

``Runner`` compiles ``rollout`` once and ``learn`` once and drives them from Python, one call each per
episode batch, so logging, progress bars and checkpoints sit between iterations; its ``evaluate`` runs
``eval_episodes`` deterministic episodes through the same rollout; ``train`` is its plain loop.
Everything a checkpoint must hold to resume lives in the one ``TrainState`` pytree (environments are
reset at every batch, so no environment state outlives an iteration).

The environment hides behind ``EnvAdapter`` (train/adapter.py); the rollout is train/rollout.py.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from mjx_push import devices, xla
from mjx_push.train import data_parallel, normalizer, replay
from mjx_push.train.adapter import EnvAdapter
from mjx_push.train.config import TrainConfig
from mjx_push.train.networks import Networks, make_networks
from mjx_push.train.normalizer import RunningStats
from mjx_push.train.replay import ReplayBuffer
from mjx_push.train.rollout import episode_means, make_collect, make_group_collect, make_split_collect
from mjx_push.train.sac import SACState, init_state, make_update
from mjx_push.errors import ConfigError

Params = Any


def spread_envs(k: int, groups: tuple[int, ...]) -> np.ndarray:
    """[sum(groups)] bool with ``k`` True, shared among the contiguous ``groups`` in proportion to
    their sizes (largest remainder) and evenly spaced within each, so the expert demonstrates every
    group (shape) and the agent's own environments keep the batch's mix."""
    n = sum(groups)
    if not 0 <= k <= n:
        raise ConfigError(f"cannot pick {k} of {n} environments")
    quota = np.array([k * g / n for g in groups])
    take = np.floor(quota).astype(int)
    for i in np.argsort(-(quota - take), kind="stable")[: k - take.sum()]:
        take[i] += 1
    out = []
    for g, t in zip(groups, take):
        mask = np.zeros(g, bool)
        mask[np.floor((np.arange(t) + 0.5) * g / max(t, 1)).astype(int)] = True
        out.append(mask)
    return np.concatenate(out)


@flax.struct.dataclass
class TrainState:
    sac: SACState
    buffer: ReplayBuffer
    key: jax.Array
    env_steps: jax.Array  # int32, environment steps collected over all envs (whole episode batches)
    best_actor_params: Params
    best_eval_reward: jax.Array  # -inf until the first evaluation
    best_eval_success: jax.Array
    best_env_steps: jax.Array  # env_steps at which the best params were evaluated (-1: none yet)
    norm_stats: dict[str, RunningStats]  # running input statistics (AgentConfig.obs_norm)
    # The actor as it was at the teacher's anneal_start, frozen after it (SACConfig.anchor_weight); a
    # copy of the initial actor, never updated, without an anchor.
    anchor_actor_params: Params


@dataclasses.dataclass(frozen=True)
class Trainer:
    config: TrainConfig
    networks: Networks
    init: Callable[[jax.Array], TrainState]
    rollout: Callable  # (actor_params, key, random_actions, deterministic, expert_envs, episodes) -> (episodes, stats)
    split_keys: Callable[[TrainState], tuple[TrainState, jax.Array, jax.Array]]
    learn: Callable[[TrainState, dict, jax.Array], tuple[TrainState, dict]]
    select: Callable[[TrainState, dict], tuple[TrainState, dict]]
    eval_key: jax.Array
    num_eval_chunks: int
    rollout_mesh: Any = None  # the devices the training rollout's environments are split over
    # How: "groups" (a program per shape group, each on devices of its own), "episodes" (each device
    # runs its share of every group's whole episodes) or "physics" (only the substeps).
    rollout_split: str | None = None
    adapter: EnvAdapter | None = None  # the environment (its expert groups and evaluation episodes)


def improves(reward, success, best_reward, best_success):
    """The best-policy rule: a higher mean evaluation reward wins; a tie goes to the newer actor unless
    its success rate is lower. With sparse rewards equal scores (e.g. -T while nothing reaches the goal
    yet) say nothing, and the longer-trained policy is the better guess. Works on arrays (jitted
    training) and on Python floats (replaying a run's metrics)."""
    return (reward > best_reward) | ((reward == best_reward) & (success >= best_success))


def make_train(config: TrainConfig, adapter: EnvAdapter, action_dim: int = 3) -> Trainer:
    loop, sac_cfg = config.loop, config.sac
    # The task's facts are the environment's: the learner reads them from its adapter only.
    T, N, success_tau = adapter.episode_len, loop.num_envs, adapter.success_tau
    config.check_task(T, success_tau)
    # Data parallel (train/data_parallel.py): these functions are one device's share of the run, N_dev
    # environments, a replay shard and a shard of every batch, with gradients averaged over `axis`.
    D = loop.data_parallel
    axis = data_parallel.AXIS if D > 1 else None
    N_dev, batch_dev, bc_batch_dev = N // D, sac_cfg.batch_size // D, sac_cfg.bc_batch_size // D
    replay_cfg = config.replay
    if D > 1:
        for name, value in (("sac.batch_size", sac_cfg.batch_size), ("sac.bc_batch_size", sac_cfg.bc_batch_size)):
            if value % D:
                raise ConfigError(f"{name} must be a multiple of loop.data_parallel ({D}), got {value}")
        shard_episodes = config.replay.capacity_transitions // T // D
        if shard_episodes < N_dev:
            raise ConfigError(
                f"replay.capacity_transitions {config.replay.capacity_transitions} over {D} devices holds "
                f"{shard_episodes} episodes per device, fewer than one batch ({N_dev})"
            )
        replay_cfg = dataclasses.replace(config.replay, capacity_transitions=shard_episodes * T)

    def on_device(key):
        """A key of this device's own (the same key everywhere when not data parallel)."""
        return key if axis is None else jax.random.fold_in(key, jax.lax.axis_index(axis))

    def everywhere(ok):
        """True where it holds on every device."""
        return ok if axis is None else jax.lax.pmin(ok.astype(jnp.int32), axis) > 0

    def total(count):
        return count if axis is None else jax.lax.psum(count, axis)

    agent, demo_cfg = config.agent, config.demo
    if demo_cfg.enabled and adapter.expert is None:
        raise ConfigError("demonstrations (demo.warmup / demo.fraction) need an environment with a scripted expert")
    privileged = agent.critic_obs == "privileged"
    nets = make_networks(agent, action_dim, adapter.priv_dim if privileged else 0)
    stored_priv_dim = adapter.priv_dim if privileged else 0
    # Behaviour cloning learns from the expert's noise-free action at every stored step: on
    # demonstrations only, or (demo.label_all) on the agent's own steps too.
    store_labels = demo_cfg.enabled

    # Iterations that run updates: those ending at or after the warm-up (for the lr decay horizon).
    steps_per_batch, updates_per_batch = loop.env_steps_per_iteration(T), loop.updates_per_iteration(T)
    first_learning_iteration = max(1, -(-loop.warmup_env_steps // steps_per_batch))
    learning_iterations = max(0, loop.num_iterations(T) - first_learning_iteration + 1)
    total_updates = learning_iterations * updates_per_batch
    update = make_update(
        config.agent, sac_cfg, action_dim, total_updates=max(total_updates, 1), nets=nets, axis_name=axis
    )
    # Evaluation always uses the same episodes (docs/task.md section 7), derived from the config's seed.
    eval_key = jax.random.fold_in(jax.random.PRNGKey(loop.seed), 0x5E1EC7)

    def init(key: jax.Array) -> TrainState:
        k_sac, k_loop = jax.random.split(key)
        sac_state = init_state(k_sac, nets, sac_cfg, T, total_updates=max(total_updates, 1))
        return TrainState(
            sac=sac_state,
            buffer=replay.init(replay_cfg, T, action_dim, stored_priv_dim, store_labels, success_tau=success_tau),
            key=k_loop,
            env_steps=jnp.zeros((), jnp.int32),
            best_actor_params=jax.tree.map(jnp.copy, sac_state.actor_params),  # no alias (donation)
            best_eval_reward=jnp.array(-jnp.inf, jnp.float32),
            best_eval_success=jnp.zeros((), jnp.float32),
            best_env_steps=jnp.array(-1, jnp.int32),
            norm_stats=normalizer.init_stats(agent.critic_obs, adapter.priv_dim) if agent.obs_norm else {},
            anchor_actor_params=jax.tree.map(jnp.copy, sac_state.actor_params),
        )

    rollout_mesh = adapter.mesh(N) if adapter.mesh and D == 1 else None
    collect, rollout_split = make_collect(config, adapter, nets), None if rollout_mesh is None else "physics"
    if rollout_mesh is not None and adapter.one_device is not None:
        # Each device runs whole episodes: no joining of devices at every tick of the rollout.
        groups = tuple(adapter.groups(N)) if adapter.groups else (N,)
        twins = [adapter.one_device(adapter, g) for g in range(len(groups))] if len(groups) > 1 else [None]
        one_per_group = None not in twins and rollout_mesh.size % len(groups) == 0
        if one_per_group and (rollout_mesh.size == len(groups) or devices.shard_map_compiles()):
            # A program per shape group on devices of its own, the groups compiled side by side.
            collect, rollout_split = make_group_collect(config, twins, nets, rollout_mesh, groups), "groups"
        elif devices.shard_map_compiles() and (twin := adapter.one_device(adapter)) is not None:
            # Each device runs its share of every group.
            collect, rollout_split = make_split_collect(config, twin, nets, rollout_mesh, groups), "episodes"

    bc = sac_cfg.bc_weight > 0
    anchored = sac_cfg.anchor_weight > 0

    def run_updates(sac_state, buffer, key, tau, bc_scale, anchor, anchor_scale):
        def body(s, k):
            k_sample, k_demo, k_update = jax.random.split(on_device(k), 3)
            batch = replay.sample(buffer, k_sample, batch_dev, success_tau=tau)
            demo = (
                replay.sample(buffer, k_demo, bc_batch_dev, demos_only=not demo_cfg.label_all, relabel=False)
                if bc
                else None
            )
            return update(s, batch, k_update, demo, bc_scale, anchor if anchored else None, anchor_scale)

        sac_state, metrics = jax.lax.scan(body, sac_state, jax.random.split(key, updates_per_batch))
        metrics = jax.tree.map(jnp.mean, metrics)
        if axis is not None:  # the devices' means, once per batch (not per update)
            metrics = data_parallel.flat_pmean(metrics, axis)
        return sac_state, metrics

    def rollout(actor_params, key, random_actions, deterministic, expert_envs=False, episodes=None):
        """One episode in each of the ``num_envs`` training envs. The flags (and ``episodes``' use
        flag) are traced, so training rollouts, demonstrations and evaluation chunks share one compiled
        function (on CPU the environment's compilation is the largest fixed cost of a run)."""
        return collect(actor_params, on_device(key), N_dev, random_actions, deterministic, expert_envs, episodes)

    def with_norm(sac_state: SACState, stats) -> SACState:
        """The networks' "norm" variables set from the running statistics."""
        return sac_state.replace(
            actor_params=normalizer.write(sac_state.actor_params, stats),
            critic_params=normalizer.write(sac_state.critic_params, stats),
            target_critic_params=normalizer.write(sac_state.target_critic_params, stats),
        )

    def split_keys(ts: TrainState):
        """-> (state with its key advanced, collection key, update key)."""
        key, k_collect, k_update = jax.random.split(ts.key, 3)
        return ts.replace(key=key), k_collect, k_update

    def learn(ts: TrainState, episodes: dict, k_update: jax.Array) -> tuple[TrainState, dict]:
        """Store a batch of episodes and run this batch's SAC updates (none during warm-up)."""
        buffer = replay.add(ts.buffer, episodes)
        env_steps = ts.env_steps + N * T
        # The teacher's annealing factor on the cloning weight, at this batch's env steps.
        bc_scale = demo_cfg.teacher_scale(env_steps)
        if not demo_cfg.keep_after_anneal:  # the expert's episodes leave with the teacher
            buffer = replay.drop_demos(buffer, demo_cfg.teacher_gone(env_steps))
        # Every device must be able to fill its shard of the batch (and of the cloning batch while the
        # cloning term counts and draws from demonstrations only: once the teacher has gone, learning
        # goes on after its last episode has left replay).
        learn = (env_steps >= loop.warmup_env_steps) & everywhere(replay.num_valid_transitions(buffer) >= batch_dev)
        if bc and not demo_cfg.label_all:
            learn = learn & (everywhere(replay.num_demo_episodes(buffer) > 0) | (bc_scale <= 0))
        norm_stats, sac_state = ts.norm_stats, ts.sac
        if agent.obs_norm:  # the statistics of every device's episodes, so they stay the same everywhere
            seen = episodes if axis is None else jax.lax.all_gather(episodes, axis, tiled=True)
            norm_stats = normalizer.update_stats(norm_stats, seen, agent.critic_obs)
            sac_state = with_norm(sac_state, norm_stats)
        tau = config.replay.reward_tau(
            jnp.maximum(env_steps - loop.warmup_env_steps, 0).astype(jnp.float32), success_tau
        )
        anchor = ts.anchor_actor_params
        anchor_scale = demo_cfg.anchor_scale(env_steps)
        args = (sac_state, buffer, k_update, tau, bc_scale, anchor, anchor_scale)
        update_metrics_shape = jax.eval_shape(run_updates, *args)[1]
        skip_metrics = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), update_metrics_shape)
        if updates_per_batch > 0:
            sac_state, update_metrics = jax.lax.cond(learn, run_updates, lambda s, *_: (s, skip_metrics), *args)
        else:
            update_metrics = skip_metrics
        if anchored:  # the actor follows itself until the teacher starts to leave, then is frozen
            follow = env_steps <= demo_cfg.anneal_start
            anchor = jax.tree.map(lambda a, h: jnp.where(follow, a, h), sac_state.actor_params, anchor)

        new_ts = ts.replace(
            sac=sac_state, buffer=buffer, env_steps=env_steps, norm_stats=norm_stats, anchor_actor_params=anchor
        )
        metrics = {
            **{f"sac/{k}": v for k, v in update_metrics.items()},
            "learning": learn,
            "env_steps": env_steps,
            "updates": sac_state.step,
            "replay/valid_episodes": total(replay.num_valid_episodes(buffer)),
            "replay/demo_episodes": total(replay.num_demo_episodes(buffer)),
            "replay/reward_tau": jnp.asarray(tau, jnp.float32),
            "demo/teacher_scale": bc_scale,
            "demo/anchor_scale": jnp.asarray(anchor_scale, jnp.float32),
        }
        return new_ts, metrics

    num_eval_chunks = -(-loop.eval_episodes // N)

    def select(ts: TrainState, stats: dict) -> tuple[TrainState, dict]:
        """Keep the actor params with the best mean evaluation reward so far (`improves`)."""
        better = improves(stats["mean_reward"], stats["success_rate"], ts.best_eval_reward, ts.best_eval_success)
        pick = lambda new, old: jax.tree.map(lambda n, o: jnp.where(better, n, o), new, old)  # noqa: E731
        ts = ts.replace(
            best_actor_params=pick(ts.sac.actor_params, ts.best_actor_params),
            best_eval_reward=pick(stats["mean_reward"], ts.best_eval_reward),
            best_eval_success=pick(stats["success_rate"], ts.best_eval_success),
            best_env_steps=pick(ts.env_steps, ts.best_env_steps),
        )
        return ts, {**{f"eval/{k}": v for k, v in stats.items()}, "eval/improved": better}

    if D > 1 and adapter.mesh and adapter.mesh(N_dev) is not None:
        raise ConfigError(
            "a data-parallel run steps each device's environments on that device: build the adapter for one device"
        )
    return Trainer(
        rollout_mesh=rollout_mesh,
        rollout_split=rollout_split,
        adapter=adapter,
        config=config,
        networks=nets,
        init=init,
        rollout=rollout,
        split_keys=split_keys,
        learn=learn,
        select=select,
        eval_key=eval_key,
        num_eval_chunks=num_eval_chunks,
    )


class Runner:
    """Host-side driver of a ``Trainer``: two compiled functions, ``rollout`` (shared by training and
    evaluation) and ``learn`` (donating the state, so the replay buffer is updated in place).

    With an adapter that defines ``eval_episodes``, in-run evaluations (and so the best actor) score
    the protocol's episodes of ``loop.eval_setting`` drawn from ``loop.eval_seed``: the same objects,
    poses and goals for every agent and training seed. Otherwise (the toy task) they draw their
    episodes from ``trainer.eval_key``."""

    def __init__(self, trainer: Trainer):
        self.trainer = trainer
        self.adapter = trainer.adapter
        self._eval_chunks: list | None = None
        self.devices = trainer.config.loop.data_parallel
        if self.devices > 1:  # one program over a mesh of devices (and processes): train/data_parallel.py
            sharded = data_parallel.Sharded(trainer, data_parallel.make_mesh(self.devices))
            self.init, self.learn, self.select, self._rollout = (
                sharded.init,
                sharded.learn,
                sharded.select,
                sharded.rollout,
            )
            return
        self.init = trainer.init
        # The updates step no physics: compiled with XLA's CPU fusion emitters (mjx_push.xla).
        self.learn = jax.jit(trainer.learn, donate_argnums=0, compiler_options=xla.physics_free_options())
        self.select = jax.jit(trainer.select, donate_argnums=0)
        if trainer.rollout_mesh is None:
            self._rollout = jax.jit(trainer.rollout)
        else:
            # The rollout's environments are split over several devices (mjx_push.devices). Its
            # arguments are replicated onto them and what it returns is gathered onto one device, so
            # the learner and its replay buffer stay single-device programs and arrays (a multi-device
            # ``learn`` would run replicated, and the shardings of the rollout's arguments would
            # change from call to call, recompiling it every batch).
            spread = jax.sharding.NamedSharding(trainer.rollout_mesh, jax.sharding.PartitionSpec())
            home = jax.sharding.SingleDeviceSharding(trainer.rollout_mesh.devices.flat[0])
            if trainer.rollout_split == "groups":  # its groups' programs place their own arguments
                self._rollout = trainer.rollout
            else:
                rollout = jax.jit(trainer.rollout)
                self._rollout = lambda *args: jax.device_put(rollout(*jax.device_put(args, spread)), home)
            # Committed to that device from the first call on (a fresh state is not), so the learner's
            # functions see the same argument placements every batch and compile once.
            learn, select = self.learn, self.select
            self.learn = lambda *args: learn(*jax.device_put(args, home))
            self.select = lambda *args: select(*jax.device_put(args, home))

    @property
    def shared_episodes(self) -> bool:
        return self.adapter is not None and self.adapter.eval_episodes is not None

    def eval_chunks(self) -> list:
        """The in-run evaluation's episodes, one pytree per chunk of ``num_envs`` (built once)."""
        if self._eval_chunks is None:
            loop = self.trainer.config.loop
            chunks, covered = [], 0
            D, n = self.devices, loop.num_envs // self.devices
            while covered < loop.eval_episodes:  # until every episode index below eval_episodes is run
                # Data parallel: each device runs a chunk of its own batch's layout, together chunk c.
                parts = [
                    jax.device_get(
                        self.adapter.eval_episodes(loop.eval_setting, loop.eval_seed, len(chunks) * D + d, n)
                    )
                    for d in range(D)
                ]
                if D > 1:
                    fields = [{k: v for k, v in part.items() if k != "use"} for part in parts]
                    parts = [{**jax.tree.map(lambda *xs: np.concatenate(xs), *fields), "use": np.asarray(True)}]
                ep = parts[0]
                covered += int(np.sum(np.asarray(ep["index"]) < loop.eval_episodes))
                chunks.append(ep)
            self._eval_chunks = chunks
        return self._eval_chunks

    def rollout(self, actor_params, key, random_actions, deterministic, expert_envs, episodes=None):
        """The compiled rollout; with shared evaluation episodes the training rollouts pass the first
        chunk with its ``use`` flag off, so both kinds of call compile to one program."""
        if self.shared_episodes:
            if episodes is None:
                episodes = {**self.eval_chunks()[0], "use": np.asarray(False)}
            return self._rollout(actor_params, key, random_actions, deterministic, expert_envs, episodes)
        if episodes is not None:
            raise ConfigError("this environment adapter defines no evaluation episodes")
        return self._rollout(actor_params, key, random_actions, deterministic, expert_envs)

    def expert_envs(self, env_steps: int) -> np.ndarray:
        """[N] bool: which environments of the next batch follow the scripted expert. During the
        warm-up all of them with ``demo.warmup`` (none otherwise: random actions); after it
        round(fraction * N * teacher_scale) of them (the annealing factor, 1 without annealing),
        spread over the adapter's shape groups in proportion (`spread_envs`). The mask is an input
        of the rollout, so every batch compiles alike."""
        cfg = self.trainer.config
        n = cfg.loop.num_envs
        if env_steps < cfg.loop.warmup_env_steps:
            return np.full(n, cfg.demo.warmup)
        k = int(round(cfg.demo.fraction * n * cfg.demo.teacher_scale(env_steps)))
        n_dev = n // self.devices  # data parallel: each device spreads its share over its own batch
        groups = self.adapter.groups(n_dev) if self.adapter is not None and self.adapter.groups else (n_dev,)
        return np.concatenate([spread_envs(k_d, tuple(groups)) for k_d in data_parallel.split_evenly(k, self.devices)])

    def iteration(self, ts: TrainState) -> tuple[TrainState, dict]:
        cfg = self.trainer.config
        ts, k_collect, k_update = self.trainer.split_keys(ts)
        steps = int(ts.env_steps)
        random_actions = jnp.asarray(steps < cfg.loop.warmup_env_steps and not cfg.demo.warmup)
        # A cloning-only actor has no entropy objective, so its sampling noise is untrained: it acts
        # deterministically, as DAgger's learner does.
        deterministic = jnp.asarray(cfg.sac.actor_loss == "bc")
        expert = self.expert_envs(steps)
        t0 = time.perf_counter()
        episodes, stats = jax.block_until_ready(
            self.rollout(ts.sac.actor_params, k_collect, random_actions, deterministic, jnp.asarray(expert))
        )
        t1 = time.perf_counter()
        ts, metrics = jax.block_until_ready(self.learn(ts, episodes, k_update))
        metrics.update(rollout_s=t1 - t0, learn_s=time.perf_counter() - t1)
        # Training metrics describe the agent's own episodes when there are any.
        own = ~expert if (~expert).any() else expert
        stats = {k: v[own] for k, v in stats.items()}
        return ts, {
            **{f"train/{k}": v for k, v in episode_means(stats).items()},
            **metrics,
            "train/expert_envs": int(expert.sum()),
        }

    def evaluate(self, actor_params, key: jax.Array | None = None, expert: bool = False) -> dict:
        """``eval_episodes`` deterministic episodes through the shared rollout (the shared episodes
        when the adapter has them, else drawn from ``key``, default the trainer's ``eval_key``), in
        episode order; per-episode arrays included. ``expert`` evaluates the environment's scripted
        expert instead of the actor."""
        t = self.trainer
        n = t.config.loop.eval_episodes
        flags = (jnp.asarray(False), jnp.asarray(True), jnp.asarray(np.full(t.config.loop.num_envs, expert)))
        if self.shared_episodes and key is None:
            chunks = self.eval_chunks()
            stats = [
                self.rollout(actor_params, jax.random.fold_in(t.eval_key, c), *flags, episodes=ep)[1]
                for c, ep in enumerate(chunks)
            ]
            index = np.concatenate([np.asarray(ep["index"]) for ep in chunks])
            order = np.argsort(index, kind="stable")
            order = order[index[order] < n]  # the protocol's first n episodes
            flat = {k: jnp.concatenate([c[k] for c in stats])[order] for k in stats[0]}
        else:
            key = t.eval_key if key is None else key
            stats = [
                self.rollout(actor_params, jax.random.fold_in(key, c), *flags)[1] for c in range(t.num_eval_chunks)
            ]
            flat = {k: jnp.concatenate([c[k] for c in stats])[:n] for k in stats[0]}
        return {**episode_means(flat), **flat}

    def eval_and_select(self, ts: TrainState) -> tuple[TrainState, dict]:
        t0 = time.perf_counter()
        stats = jax.block_until_ready(self.evaluate(ts.sac.actor_params))
        ts, metrics = self.select(ts, {k: v for k, v in stats.items() if not k.startswith("episode_")})
        return ts, {**metrics, "eval_s": time.perf_counter() - t0}

    def is_eval_iteration(self, i: int) -> bool:
        """Evaluate after iteration ``i`` (0-based) when it crosses a multiple of eval_every_env_steps,
        and after the last one."""
        loop, T = self.trainer.config.loop, self.trainer.adapter.episode_len
        steps, every = (i + 1) * loop.env_steps_per_iteration(T), loop.eval_every_env_steps
        crossed = steps // every > (steps - loop.env_steps_per_iteration(T)) // every
        return crossed or i == loop.num_iterations(T) - 1


def train(
    key: jax.Array,
    config: TrainConfig,
    adapter: EnvAdapter,
    callback: Callable[[TrainState, dict], bool | None] | None = None,
    trainer: Trainer | None = None,
    state: TrainState | None = None,
    runner: Runner | None = None,
) -> tuple[TrainState, list[dict]]:
    """Run ``config.loop.total_env_steps`` (rounded up to whole episode batches).

    Evaluates every ``eval_every_env_steps`` and after the last iteration, keeping the best actor
    params by mean reward in the returned state. ``callback(state, metrics)`` runs after every
    iteration (metrics as Python numbers); returning True stops early. The state passed to the
    callback is donated to the next iteration: copy what you keep (e.g. ``jax.device_get``).
    Pass ``trainer`` / ``runner`` to reuse compiled functions and ``state`` to resume.
    """
    if runner is None:
        runner = Runner(trainer if trainer is not None else make_train(config, adapter))
    loop, T = config.loop, runner.trainer.adapter.episode_len
    ts = state if state is not None else runner.init(key)

    history: list[dict] = []
    start = int(ts.env_steps) // loop.env_steps_per_iteration(T)
    for i in range(start, loop.num_iterations(T)):
        ts, metrics = runner.iteration(ts)
        if runner.is_eval_iteration(i):
            ts, eval_metrics = runner.eval_and_select(ts)
            metrics.update(eval_metrics)
        metrics = {k: np.asarray(v).item() for k, v in metrics.items()}
        history.append(metrics)
        if callback is not None and callback(ts, metrics) is True:
            break
    return ts, history

"""Jitted rollout + update loop (brax / purejaxrl style) and its host driver.

``make_train(config, adapter)`` returns pure, jittable pieces:

* ``init(key) -> TrainState``
* ``rollout(actor_params, key, random_actions, deterministic) -> (episodes, stats)``: one whole
  episode in each of ``num_envs`` environments (the policy acts step by step with its carry; uniform
  random actions during warm-up), in lockstep (``lax.scan`` over ``adapter.step``) or, when the
  adapter has a ``SubstepScheduler``, each environment at its own pace. Evaluation reuses it chunk by
  chunk.
* ``learn(state, episodes, key)``: add the episodes to replay, then ``lax.scan`` over
  ``num_envs * episode_len * utd`` SAC updates (skipped until warm-up is over and replay holds at
  least ``batch_size`` valid transitions); ``split_keys`` derives the two keys from the state's.
* ``select(state, eval_stats)`` keeps the best actor params by mean evaluation reward (the reference's
  selection).

``Runner`` jits ``rollout`` once and ``learn`` once and drives them from Python, one call each per
episode batch, so logging, progress bars and checkpoints sit between iterations; its ``evaluate`` runs
``eval_episodes`` deterministic episodes through the same rollout; ``train`` is its plain loop. Everything a checkpoint must hold to resume lives in the one ``TrainState`` pytree
(environments are reset at every batch, so no environment state outlives an iteration).

The environment hides behind ``EnvAdapter`` (pure functions), so the same code runs the toy task in
the tests and the MJX pushing environment:

* ``reset(key, num_envs) -> (env_state, step_obs, episode_info)``, ``step_obs`` = {``ee_xy [N, 2]``,
  ``z_obj [N, 6]``, ``obj_xy [N, 2]``} (+ ``priv [N, priv_dim]``), ``episode_info`` = {``z_goal [N, 6]``,
  ``goal_xy [N, 2]``};
* ``step(env_state, action [N, 3] in [-1, 1]) -> (env_state, step_obs, invalid [N] bool)``. An
  episode with any invalid step is stored with ``valid=False`` and never sampled;
* optionally ``success_tau``, the task's success radius, checked against ``replay.success_tau``;
* optionally ``scheduler`` (``SubstepScheduler``), the step in phases for asynchronous rollouts;
* optionally ``priv_dim`` > 0: ``step_obs["priv"]`` is the ground-truth state a privileged critic
  reads (its first two numbers are the object's xy);
* optionally ``expert(step_obs, episode_info) -> action [N, 3]``: a scripted policy on the ground
  truth, for demonstrations (``DemoConfig``) and as a baseline;
* optionally ``groups(num_envs) -> sizes``: the contiguous groups a batch is laid out in (the pushing
  scene's shape groups), over which the expert's environments are spread in proportion;
* optionally ``eval_episodes(setting, seed, chunk, num_envs) -> episodes``: the protocol's evaluation
  episodes as a pytree (``use``, ``index`` [N], and whatever the adapter's ``reset(key, num_envs,
  episodes)`` needs to start them where ``use`` is True), so in-run evaluations score every agent on
  the same objects, poses and goals.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from train import normalizer, replay
from train.config import TrainConfig
from train.networks import Networks, make_networks
from train.normalizer import RunningStats
from train.replay import ReplayBuffer
from train.sac import SACState, init_state, make_update

Params = Any


def select_envs(mask: jax.Array, new, old):
    """Per environment (leading axis), ``new`` where ``mask`` [N] is True and ``old`` elsewhere."""
    return jax.tree.map(lambda n, o: jnp.where(mask.reshape(mask.shape + (1,) * (n.ndim - 1)), n, o), new, old)


@dataclasses.dataclass(frozen=True)
class SubstepScheduler:
    """The step of an environment whose steps last a variable number of substeps, in phases, so the
    rollout can advance every environment ``chunk`` substeps at a time and give each its next action
    as soon as its own step is done (instead of every step waiting for the slowest environment):

    * ``begin(env_state, action [N, 3], mask [N]) -> env_state``: start a step where ``mask``;
    * ``advance(env_state, chunk) -> env_state``: up to ``chunk`` substeps of every current step;
    * ``ready(env_state) -> [N] bool``: the current step's substeps are spent;
    * ``finish(env_state, mask) -> (env_state, step_obs, invalid)``: end the step where ``mask``.
    """

    begin: Callable[[Any, jax.Array, jax.Array], Any]
    advance: Callable[[Any, int], Any]
    ready: Callable[[Any], jax.Array]
    finish: Callable[[Any, jax.Array], tuple[Any, dict, jax.Array]]
    chunk: int

    def __post_init__(self):
        if not (isinstance(self.chunk, int) and self.chunk >= 1):
            raise ValueError(f"substep chunk must be a positive integer, got {self.chunk!r}")


@dataclasses.dataclass(frozen=True)
class EnvAdapter:
    reset: Callable[[jax.Array, int], tuple[Any, dict, dict]]
    step: Callable[[Any, jax.Array], tuple[Any, dict, jax.Array]]
    # The task's success radius, if the environment defines one: make_train checks that the learner's
    # reward (ReplayConfig.success_tau) uses the same, so relabelled rewards match the task's.
    success_tau: float | None = None
    # When set, rollouts step the environments asynchronously through it; the episodes are the same
    # as with ``step`` (every random draw is keyed by environment and step), only faster.
    scheduler: SubstepScheduler | None = None
    priv_dim: int = 0
    expert: Callable[[dict, dict], jax.Array] | None = None
    # The devices a batch of ``num_envs`` environments is split over (a jax Mesh), or None for one.
    mesh: Callable[[int], Any] | None = None
    groups: Callable[[int], tuple[int, ...]] | None = None
    eval_episodes: Callable[[str, int, int, int], dict] | None = None


def spread_envs(k: int, groups: tuple[int, ...]) -> np.ndarray:
    """[sum(groups)] bool with ``k`` True, shared among the contiguous ``groups`` in proportion to
    their sizes (largest remainder) and evenly spaced within each, so the expert demonstrates every
    group (shape) and the agent's own environments keep the batch's mix."""
    n = sum(groups)
    if not 0 <= k <= n:
        raise ValueError(f"cannot pick {k} of {n} environments")
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
    adapter: EnvAdapter | None = None  # the environment (its expert groups and evaluation episodes)


def episode_stats(episodes: dict, success_tau: float) -> dict:
    """Per-episode sum of sparse rewards, final success, validity and the object's distance to its goal
    at the start and the end (``summarize`` gives the means); invalid episodes count as failures with
    the worst reward -T and no progress (their ground truth may be garbage)."""
    T = episodes["action"].shape[1]
    rewards = replay.sparse_reward(episodes["obj_xy"][:, 1:], episodes["goal_xy"][:, None], success_tau)
    start_dist = jnp.linalg.norm(episodes["obj_xy"][:, 0] - episodes["goal_xy"], axis=-1)
    final_dist = jnp.linalg.norm(episodes["obj_xy"][:, -1] - episodes["goal_xy"], axis=-1)
    valid = episodes["valid"]
    ep_reward = jnp.where(valid, jnp.sum(rewards, axis=1), -float(T))
    success = valid & (final_dist < success_tau)
    return {
        "episode_success": success,
        "episode_reward": ep_reward,
        "episode_valid": valid,
        "episode_start_distance": start_dist,
        "episode_final_distance": jnp.where(valid, final_dist, start_dist),
    }


# Radii (m) at which training and evaluation also report success, whatever the task's radius.
REPORT_RADII = (0.01, 0.02, 0.05)


def summarize(stats: dict, n: int | None = None) -> dict:
    """Means over the first ``n`` episodes of per-episode stats (all if None)."""
    s = stats["episode_success"][:n].astype(jnp.float32)
    valid = stats["episode_valid"][:n]
    final = stats["episode_final_distance"][:n]
    at = {f"success_{round(r * 100)}cm": jnp.mean((valid & (final < r)).astype(jnp.float32)) for r in REPORT_RADII}
    return {
        "success_rate": jnp.mean(s),
        **at,
        "mean_reward": jnp.mean(stats["episode_reward"][:n]),
        "invalid_rate": 1.0 - jnp.mean(stats["episode_valid"][:n].astype(jnp.float32)),
        # Progress the sparse reward cannot show: while nothing reaches 1 cm every reward is -T.
        "start_distance": jnp.mean(stats["episode_start_distance"][:n]),
        "final_distance": jnp.mean(stats["episode_final_distance"][:n]),
    }


def improves(reward, success, best_reward, best_success):
    """The best-policy rule: a higher mean evaluation reward wins; a tie goes to the newer actor unless
    its success rate is lower. With sparse rewards equal scores (e.g. -T while nothing reaches the goal
    yet) say nothing, and the longer-trained policy is the better guess. Works on arrays (jitted
    training) and on Python floats (replaying a run's metrics)."""
    return (reward > best_reward) | ((reward == best_reward) & (success >= best_success))


def make_train(config: TrainConfig, adapter: EnvAdapter, action_dim: int = 3) -> Trainer:
    loop, sac_cfg = config.loop, config.sac
    if adapter.success_tau is not None and abs(adapter.success_tau - config.replay.success_tau) > 1e-12:
        raise ValueError(
            f"replay.success_tau must equal the environment's success radius {adapter.success_tau}, "
            f"got {config.replay.success_tau}"
        )
    T, N = loop.episode_len, loop.num_envs
    agent, demo_cfg = config.agent, config.demo
    if demo_cfg.enabled and adapter.expert is None:
        raise ValueError("demonstrations (demo.warmup / demo.fraction) need an environment with a scripted expert")
    privileged = agent.critic_obs == "privileged"
    nets = make_networks(agent, action_dim, adapter.priv_dim if privileged else 0)
    stored_priv_dim = adapter.priv_dim if privileged else 0
    # Behaviour cloning learns from the expert's noise-free action at every stored step: on
    # demonstrations only, or (demo.label_all) on the agent's own steps too.
    store_labels = demo_cfg.enabled

    # Iterations that run updates: those ending at or after the warm-up (for the lr decay horizon).
    first_learning_iteration = max(1, -(-loop.warmup_env_steps // loop.env_steps_per_iteration))
    learning_iterations = max(0, loop.num_iterations - first_learning_iteration + 1)
    total_updates = learning_iterations * loop.updates_per_iteration
    update = make_update(config.agent, sac_cfg, action_dim, total_updates=max(total_updates, 1), nets=nets)
    # Evaluation always uses the same episodes (docs/task.md section 7), derived from the config's seed.
    eval_key = jax.random.fold_in(jax.random.PRNGKey(loop.seed), 0x5E1EC7)

    def init(key: jax.Array) -> TrainState:
        k_sac, k_loop = jax.random.split(key)
        sac_state = init_state(k_sac, nets, sac_cfg, T, total_updates=max(total_updates, 1))
        return TrainState(
            sac=sac_state,
            buffer=replay.init(config.replay, T, action_dim, stored_priv_dim, store_labels),
            key=k_loop,
            env_steps=jnp.zeros((), jnp.int32),
            best_actor_params=jax.tree.map(jnp.copy, sac_state.actor_params),  # no alias (donation)
            best_eval_reward=jnp.array(-jnp.inf, jnp.float32),
            best_eval_success=jnp.zeros((), jnp.float32),
            best_env_steps=jnp.array(-1, jnp.int32),
            norm_stats=normalizer.init_stats(agent.critic_obs, adapter.priv_dim) if agent.obs_norm else {},
        )

    def act(actor_params, carry, obs, info, keys, random_actions, deterministic, expert_envs):
        """Action records [N, A] (or [N, 2A] with the expert's noise-free action appended, when the
        learner stores expert labels) of every environment from its own key ([N, 2]): uniform actions
        during a random warm-up, the expert's (plus DemoConfig.noise) where ``expert_envs`` [N], else
        the policy's. The carry advances in every case, so it stays in step with the observations."""
        k_act, k_rand = jnp.swapaxes(jax.vmap(jax.random.split)(keys), 0, 1)
        policy_action, carry = nets.act(
            actor_params, carry, {"ee_xy": obs["ee_xy"], "z_obj": obs["z_obj"], "z_goal": info["z_goal"]}, k_act,
            deterministic,
        )
        uniform = jax.vmap(lambda k: jax.random.uniform(k, policy_action.shape[1:], minval=-1.0, maxval=1.0))(k_rand)
        action = jnp.where(random_actions, uniform, policy_action)
        if adapter.expert is not None:
            expert = adapter.expert(obs, info)
            noise = demo_cfg.noise * jax.vmap(lambda k: jax.random.normal(k, policy_action.shape[1:]))(k_rand)
            action = jnp.where(expert_envs[:, None], jnp.clip(expert + noise, -1.0, 1.0), action)
            if store_labels:
                action = jnp.concatenate([action, expert], axis=1)
        return action, carry

    def step_keys(step_key: jax.Array, num_envs: int) -> jax.Array:
        """[N, 2]: environment i's key for the step whose key is ``step_key``."""
        return jax.vmap(lambda i: jax.random.fold_in(step_key, i))(jnp.arange(num_envs))

    def lockstep(actor_params, env_state, obs0, info, ks, num_envs, random_actions, deterministic, expert_envs):
        def body(c, k):
            env_state, obs, carry, bad = c
            action, carry = act(actor_params, carry, obs, info, step_keys(k, num_envs), random_actions,
                                deterministic, expert_envs)
            env_state, obs, invalid = adapter.step(env_state, action[:, :action_dim])
            return (env_state, obs, carry, bad | invalid), (obs, action)

        init_c = (env_state, obs0, nets.init_carry(num_envs), jnp.zeros((num_envs,), bool))
        (_, _, _, bad), (obs_seq, actions) = jax.lax.scan(body, init_c, ks)
        return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), obs_seq), jnp.swapaxes(actions, 0, 1), bad

    def scheduled(actor_params, env_state, obs0, info, ks, num_envs, random_actions, deterministic, expert_envs):
        """Every environment runs its own T steps: each tick advances all by ``chunk`` substeps, then
        those whose step is spent finish it, record it and begin their next one."""
        sch = adapter.scheduler
        idx = jnp.arange(num_envs)
        keys_at = lambda t: jax.vmap(jax.random.fold_in)(ks[jnp.minimum(t, T - 1)], idx)  # noqa: E731
        t0 = jnp.zeros((num_envs,), jnp.int32)
        action, carry = act(actor_params, nets.init_carry(num_envs), obs0, info, keys_at(t0),
                            random_actions, deterministic, expert_envs)
        env_state = sch.begin(env_state, action[:, :action_dim], jnp.ones((num_envs,), bool))
        obs_buf = jax.tree.map(lambda x: jnp.zeros((num_envs, T) + x.shape[1:], x.dtype), obs0)
        act_buf = jnp.zeros((num_envs, T) + action.shape[1:], action.dtype).at[:, 0].set(action)

        def put(buf, slot, rows, mask):  # buf[i, slot[i]] = rows[i] where mask[i]
            return buf.at[idx, slot].set(select_envs(mask, rows, buf[idx, slot]))

        def body(c):
            env_state = sch.advance(c[0], sch.chunk)
            done = sch.ready(env_state) & (c[1] < T)
            # Finishing, encoding and acting cost a sizeable fraction of a chunk of physics: skip them
            # on the ticks where no environment's step ended.
            return jax.lax.cond(jnp.any(done), turn, lambda c, d: c, (env_state,) + c[1:], done)

        def turn(c, done):
            env_state, t, carry, obs_buf, act_buf, bad = c
            env_state, obs, invalid = sch.finish(env_state, done)
            slot = jnp.minimum(t, T - 1)
            obs_buf = jax.tree.map(lambda b, o: put(b, slot, o, done), obs_buf, obs)
            bad = bad | (done & invalid)
            t = t + done.astype(jnp.int32)
            more = done & (t < T)
            action, new_carry = act(actor_params, carry, obs, info, keys_at(t), random_actions,
                                    deterministic, expert_envs)
            carry = select_envs(more, new_carry, carry)
            env_state = sch.begin(env_state, action[:, :action_dim], more)
            act_buf = put(act_buf, jnp.minimum(t, T - 1), action, more)
            return env_state, t, carry, obs_buf, act_buf, bad

        init_c = (env_state, t0, carry, obs_buf, act_buf, jnp.zeros((num_envs,), bool))
        _, _, _, obs_buf, act_buf, bad = jax.lax.while_loop(lambda c: jnp.any(c[1] < T), body, init_c)
        return obs_buf, act_buf, bad

    def collect(actor_params, key, num_envs: int, random_actions, deterministic, expert_envs, episodes=None):
        """One whole episode in ``num_envs`` envs -> (episode records [num_envs, ...], stats). Step t
        of environment i draws its randomness from fold_in(key_t, i), so an episode does not depend on
        how the environments were scheduled. ``episodes`` (``adapter.eval_episodes``) starts the
        protocol's episodes instead of freshly drawn ones where its ``use`` flag is True."""
        k_reset, k_roll = jax.random.split(key)
        if episodes is None:
            env_state, obs0, info = adapter.reset(k_reset, num_envs)
        else:
            env_state, obs0, info = adapter.reset(k_reset, num_envs, episodes)
        run = scheduled if adapter.scheduler is not None else lockstep
        expert_envs = jnp.broadcast_to(expert_envs, (num_envs,))
        obs_seq, records, bad = run(actor_params, env_state, obs0, info, jax.random.split(k_roll, T), num_envs,
                                    random_actions, deterministic, expert_envs)
        actions = records[..., :action_dim]

        def with_reset(name):  # [N, T+1, .]: the reset observation first, then the T step observations
            return jnp.concatenate([obs0[name][:, None], obs_seq[name]], axis=1)

        episodes = {
            "z_obj": with_reset("z_obj"),
            "ee_xy": with_reset("ee_xy"),
            "obj_xy": with_reset("obj_xy"),
            "z_goal": info["z_goal"],
            "goal_xy": info["goal_xy"],
            "action": actions,
            "valid": ~bad,
            "demo": expert_envs,
        }
        if stored_priv_dim:
            episodes["priv"] = with_reset("priv")
        if store_labels:
            episodes["expert_action"] = records[..., action_dim:]
        return episodes, episode_stats(episodes, config.replay.success_tau)

    bc = sac_cfg.bc_weight > 0

    def run_updates(sac_state, buffer, key, tau, bc_scale):
        def body(s, k):
            k_sample, k_demo, k_update = jax.random.split(k, 3)
            batch = replay.sample(buffer, k_sample, sac_cfg.batch_size, success_tau=tau)
            demo = (replay.sample(buffer, k_demo, sac_cfg.bc_batch_size, demos_only=not demo_cfg.label_all,
                                  relabel=False) if bc else None)
            return update(s, batch, k_update, demo, bc_scale)

        sac_state, metrics = jax.lax.scan(body, sac_state, jax.random.split(key, loop.updates_per_iteration))
        return sac_state, jax.tree.map(jnp.mean, metrics)

    def rollout(actor_params, key, random_actions, deterministic, expert_envs=False, episodes=None):
        """One episode in each of the ``num_envs`` training envs. The flags (and ``episodes``' use
        flag) are traced, so training rollouts, demonstrations and evaluation chunks share one compiled
        function (on CPU the environment's compilation is the largest fixed cost of a run)."""
        return collect(actor_params, key, N, random_actions, deterministic, expert_envs, episodes)

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
        learn = (env_steps >= loop.warmup_env_steps) & (replay.num_valid_transitions(buffer) >= sac_cfg.batch_size)
        if bc:
            learn = learn & (replay.num_demo_episodes(buffer) > 0)
        norm_stats, sac_state = ts.norm_stats, ts.sac
        if agent.obs_norm:
            norm_stats = normalizer.update_stats(norm_stats, episodes, agent.critic_obs)
            sac_state = with_norm(sac_state, norm_stats)
        tau = config.replay.reward_tau(jnp.maximum(env_steps - loop.warmup_env_steps, 0).astype(jnp.float32))
        # The teacher's annealing factor on the cloning weight, at this batch's env steps.
        bc_scale = demo_cfg.teacher_scale(env_steps)

        update_metrics_shape = jax.eval_shape(run_updates, sac_state, buffer, k_update, tau, bc_scale)[1]
        skip_metrics = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), update_metrics_shape)
        if loop.updates_per_iteration > 0:
            sac_state, update_metrics = jax.lax.cond(
                learn, run_updates, lambda s, b, k, t, w: (s, skip_metrics), sac_state, buffer, k_update, tau,
                bc_scale)
        else:
            update_metrics = skip_metrics

        new_ts = ts.replace(sac=sac_state, buffer=buffer, env_steps=env_steps, norm_stats=norm_stats)
        metrics = {
            **{f"sac/{k}": v for k, v in update_metrics.items()},
            "learning": learn,
            "env_steps": env_steps,
            "updates": sac_state.step,
            "replay/valid_episodes": replay.num_valid_episodes(buffer),
            "replay/demo_episodes": replay.num_demo_episodes(buffer),
            "replay/reward_tau": jnp.asarray(tau, jnp.float32),
            "demo/teacher_scale": bc_scale,
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

    return Trainer(
        rollout_mesh=adapter.mesh(N) if adapter.mesh else None,
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
        self.learn = jax.jit(trainer.learn, donate_argnums=0)
        self.select = jax.jit(trainer.select, donate_argnums=0)
        rollout = jax.jit(trainer.rollout)
        if trainer.rollout_mesh is None:
            self._rollout = rollout
        else:
            # The rollout's environments are split over several devices (mjx_push.devices). Its
            # arguments are replicated onto them and what it returns is gathered onto one device, so
            # the learner and its replay buffer stay single-device programs and arrays (a multi-device
            # ``learn`` would run replicated, and the shardings of the rollout's arguments would
            # change from call to call, recompiling it every batch).
            spread = jax.sharding.NamedSharding(trainer.rollout_mesh, jax.sharding.PartitionSpec())
            home = jax.sharding.SingleDeviceSharding(jax.devices()[0])
            self._rollout = lambda *args: jax.device_put(rollout(*jax.device_put(args, spread)), home)
            # Committed to that device from the first call on (a fresh state is not), so the learner's
            # functions see the same argument placements every batch and compile once.
            learn, select = self.learn, self.select
            self.learn = lambda *args: learn(*jax.device_put(args, home))
            self.select = lambda *args: select(*jax.device_put(args, home))
        self._eval_chunks: list | None = None

    @property
    def shared_episodes(self) -> bool:
        return self.adapter is not None and self.adapter.eval_episodes is not None

    def eval_chunks(self) -> list:
        """The in-run evaluation's episodes, one pytree per chunk of ``num_envs`` (built once)."""
        if self._eval_chunks is None:
            loop = self.trainer.config.loop
            chunks, covered = [], 0
            while covered < loop.eval_episodes:  # until every episode index below eval_episodes is run
                ep = jax.device_get(self.adapter.eval_episodes(loop.eval_setting, loop.eval_seed, len(chunks),
                                                               loop.num_envs))
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
            raise ValueError("this environment adapter defines no evaluation episodes")
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
        groups = self.adapter.groups(n) if self.adapter is not None and self.adapter.groups else (n,)
        return spread_envs(k, tuple(groups))

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
            self.rollout(ts.sac.actor_params, k_collect, random_actions, deterministic, jnp.asarray(expert)))
        t1 = time.perf_counter()
        ts, metrics = jax.block_until_ready(self.learn(ts, episodes, k_update))
        metrics.update(rollout_s=t1 - t0, learn_s=time.perf_counter() - t1)
        # Training metrics describe the agent's own episodes when there are any.
        own = ~expert if (~expert).any() else expert
        stats = {k: v[own] for k, v in stats.items()}
        return ts, {**{f"train/{k}": v for k, v in summarize(stats).items()}, **metrics,
                    "train/expert_envs": int(expert.sum())}

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
            stats = [self.rollout(actor_params, jax.random.fold_in(t.eval_key, c), *flags, episodes=ep)[1]
                     for c, ep in enumerate(chunks)]
            index = np.concatenate([np.asarray(ep["index"]) for ep in chunks])
            order = np.argsort(index, kind="stable")
            order = order[index[order] < n]  # the protocol's first n episodes
            flat = {k: jnp.concatenate([c[k] for c in stats])[order] for k in stats[0]}
        else:
            key = t.eval_key if key is None else key
            stats = [self.rollout(actor_params, jax.random.fold_in(key, c), *flags)[1]
                     for c in range(t.num_eval_chunks)]
            flat = {k: jnp.concatenate([c[k] for c in stats])[:n] for k in stats[0]}
        return {**summarize(flat), **flat}

    def eval_and_select(self, ts: TrainState) -> tuple[TrainState, dict]:
        t0 = time.perf_counter()
        stats = jax.block_until_ready(self.evaluate(ts.sac.actor_params))
        ts, metrics = self.select(ts, {k: v for k, v in stats.items() if not k.startswith("episode_")})
        return ts, {**metrics, "eval_s": time.perf_counter() - t0}

    def is_eval_iteration(self, i: int) -> bool:
        """Evaluate after iteration ``i`` (0-based) when it crosses a multiple of eval_every_env_steps,
        and after the last one."""
        loop = self.trainer.config.loop
        steps, every = (i + 1) * loop.env_steps_per_iteration, loop.eval_every_env_steps
        crossed = steps // every > (steps - loop.env_steps_per_iteration) // every
        return crossed or i == loop.num_iterations - 1


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
    loop = config.loop
    ts = state if state is not None else runner.trainer.init(key)

    history: list[dict] = []
    start = int(ts.env_steps) // loop.env_steps_per_iteration
    for i in range(start, loop.num_iterations):
        ts, metrics = runner.iteration(ts)
        if runner.is_eval_iteration(i):
            ts, eval_metrics = runner.eval_and_select(ts)
            metrics.update(eval_metrics)
        metrics = {k: np.asarray(v).item() for k, v in metrics.items()}
        history.append(metrics)
        if callback is not None and callback(ts, metrics) is True:
            break
    return ts, history

"""Rollouts: one whole episode in each environment of a batch, as the learner stores it, and the
per-episode statistics training and evaluation report.

``make_collect(config, adapter, nets)`` returns ``collect(actor_params, key, num_envs, random_actions,
deterministic, expert_envs, episodes=None) -> (episodes, stats)``: the policy acts step by step with
its carry (uniform random actions during a random warm-up; the scripted expert's where ``expert_envs``),
in lockstep (``lax.scan`` over ``adapter.step``) or, when the adapter has a ``SubstepScheduler``, each
environment at its own pace (faster; the episodes start alike, then part by float rounding, which
an integer substep count can grow). ``make_split_collect`` gives the same
``collect`` with a batch split over host devices by whole episodes. With stored expert labels (demonstrations)
each step's record holds the expert's noise-free action beside the action taken, and it comes out as
``episodes["expert_action"]``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P

from mjx_push import devices, task_rules
from mjx_push.errors import ConfigError
from mjx_push.train import replay
from mjx_push.train.adapter import EnvAdapter, select_envs
from mjx_push.train.config import TrainConfig
from mjx_push.train.networks import Networks


def episode_stats(episodes: dict, success_tau: float) -> dict:
    """Per-episode sum of sparse rewards, final success, validity and the object's distance to its goal
    at the start and the end (``episode_means`` gives the means); invalid episodes count as failures with
    the worst reward -T and no progress (their ground truth may be garbage)."""
    T = episodes["action"].shape[1]
    rewards = replay.sparse_reward(episodes["obj_xy"][:, 1:], episodes["goal_xy"][:, None], success_tau)
    start_dist = jnp.linalg.norm(episodes["obj_xy"][:, 0] - episodes["goal_xy"], axis=-1)
    final_dist = jnp.linalg.norm(episodes["obj_xy"][:, -1] - episodes["goal_xy"], axis=-1)
    valid = episodes["valid"]
    ep_reward = jnp.where(valid, jnp.sum(rewards, axis=1), -float(T))
    success = valid & task_rules.reached(final_dist, success_tau)
    return {
        "episode_success": success,
        "episode_reward": ep_reward,
        "episode_valid": valid,
        "episode_start_distance": start_dist,
        "episode_final_distance": jnp.where(valid, final_dist, start_dist),
    }


# Radii (m) at which training and evaluation also report success, whatever the task's radius.
REPORT_RADII = (0.01, 0.02, 0.05)


def episode_means(stats: dict, n: int | None = None) -> dict:
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


def make_run_envs(config: TrainConfig, adapter: EnvAdapter, nets: Networks):
    """``run_envs``, the episodes of a batch's environments (``make_collect`` and ``make_split_collect``)."""
    T = adapter.episode_len  # the task's
    demo_cfg = config.demo
    stored_priv_dim = adapter.priv_dim if config.agent.critic_obs == "privileged" else 0
    # Behaviour cloning learns from the expert's noise-free action at every stored step: on
    # demonstrations only, or (demo.label_all) on the agent's own steps too.
    store_labels = demo_cfg.enabled

    def act(actor_params, carry, obs, info, keys, random_actions, deterministic, expert_envs):
        """The step's record of every environment, from its own key ([N, 2]): ``{"action": [N, A]}``,
        uniform actions during a random warm-up, the expert's (plus DemoConfig.noise) where
        ``expert_envs`` [N], else the policy's; with ``"expert_action"`` [N, A] beside it, the expert's
        noise-free action, when the learner stores expert labels. The carry advances in every case, so
        it stays in step with the observations."""
        k_act, k_rand = jnp.swapaxes(jax.vmap(jax.random.split)(keys), 0, 1)
        policy_action, carry = nets.act(
            actor_params,
            carry,
            {"ee_xy": obs["ee_xy"], "z_obj": obs["z_obj"], "z_goal": info["z_goal"]},
            k_act,
            deterministic,
        )
        uniform = jax.vmap(lambda k: jax.random.uniform(k, policy_action.shape[1:], minval=-1.0, maxval=1.0))(k_rand)
        action = jnp.where(random_actions, uniform, policy_action)
        record = {"action": action}
        if adapter.expert is not None:
            expert = adapter.expert(obs, info)
            noise = demo_cfg.noise * jax.vmap(lambda k: jax.random.normal(k, policy_action.shape[1:]))(k_rand)
            record["action"] = jnp.where(expert_envs[:, None], jnp.clip(expert + noise, -1.0, 1.0), action)
            if store_labels:
                record["expert_action"] = expert
        return record, carry

    def step_keys(step_key: jax.Array, env_ids: jax.Array) -> jax.Array:
        """[n, 2]: each environment's key for the step whose key is ``step_key`` (by its index in the batch)."""
        return jax.vmap(lambda i: jax.random.fold_in(step_key, i))(env_ids)

    def lockstep(actor_params, env_state, obs0, info, ks, env_ids, random_actions, deterministic, expert_envs):
        n = env_ids.shape[0]

        def body(c, k):
            env_state, obs, carry, bad = c
            record, carry = act(
                actor_params, carry, obs, info, step_keys(k, env_ids), random_actions, deterministic, expert_envs
            )
            env_state, obs, invalid = adapter.step(env_state, record["action"])
            return (env_state, obs, carry, bad | invalid), (obs, record)

        init_c = (env_state, obs0, nets.init_carry(n), jnp.zeros((n,), bool))
        (_, _, _, bad), (obs_seq, records) = jax.lax.scan(body, init_c, ks)
        env_major = lambda tree: jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), tree)  # noqa: E731
        return env_major(obs_seq), env_major(records), bad

    def scheduled(actor_params, env_state, obs0, info, ks, env_ids, random_actions, deterministic, expert_envs):
        """Every environment runs its own T steps: each tick advances all by ``chunk`` substeps, then
        those whose step is spent finish it, record it and begin their next one."""
        sch = adapter.scheduler
        n = env_ids.shape[0]
        idx = jnp.arange(n)
        keys_at = lambda t: jax.vmap(jax.random.fold_in)(ks[jnp.minimum(t, T - 1)], env_ids)  # noqa: E731
        t0 = jnp.zeros((n,), jnp.int32)
        record, carry = act(
            actor_params, nets.init_carry(n), obs0, info, keys_at(t0), random_actions, deterministic, expert_envs
        )
        env_state = sch.begin(env_state, record["action"], jnp.ones((n,), bool))
        obs_buf = jax.tree.map(lambda x: jnp.zeros((n, T) + x.shape[1:], x.dtype), obs0)
        rec_buf = jax.tree.map(lambda x: jnp.zeros((n, T) + x.shape[1:], x.dtype).at[:, 0].set(x), record)

        def put(buf, slot, rows, mask):  # buf[i, slot[i]] = rows[i] where mask[i]
            return buf.at[idx, slot].set(select_envs(mask, rows, buf[idx, slot]))

        def body(c):
            env_state = sch.advance(c[0], sch.chunk)
            done = sch.ready(env_state) & (c[1] < T)
            # Finishing, encoding and acting cost a sizeable fraction of a chunk of physics: skip them
            # on the ticks where no environment's step ended.
            return jax.lax.cond(jnp.any(done), turn, lambda c, d: c, (env_state,) + c[1:], done)

        def turn(c, done):
            env_state, t, carry, obs_buf, rec_buf, bad = c
            env_state, obs, invalid = sch.finish(env_state, done)
            slot = jnp.minimum(t, T - 1)
            obs_buf = jax.tree.map(lambda b, o: put(b, slot, o, done), obs_buf, obs)
            bad = bad | (done & invalid)
            t = t + done.astype(jnp.int32)
            more = done & (t < T)
            record, new_carry = act(
                actor_params, carry, obs, info, keys_at(t), random_actions, deterministic, expert_envs
            )
            carry = select_envs(more, new_carry, carry)
            env_state = sch.begin(env_state, record["action"], more)
            rec_buf = jax.tree.map(lambda b, r: put(b, jnp.minimum(t, T - 1), r, more), rec_buf, record)
            return env_state, t, carry, obs_buf, rec_buf, bad

        init_c = (env_state, t0, carry, obs_buf, rec_buf, jnp.zeros((n,), bool))
        _, _, _, obs_buf, rec_buf, bad = jax.lax.while_loop(lambda c: jnp.any(c[1] < T), body, init_c)
        return obs_buf, rec_buf, bad

    def run_envs(actor_params, reset_keys, ks, env_ids, random_actions, deterministic, expert_envs, episodes=None):
        """The episodes (records, no statistics) of the environments ``env_ids`` [n] of a batch, run as
        a batch of n: what ``adapter.reset`` takes (the batch's reset key, or the environments' own
        keys [n, 2] for a share of a larger batch), the batch's step keys ``ks`` [T, 2], the flags,
        their ``expert_envs`` [n] and their share of ``episodes``. Step t of environment i draws from
        fold_in(ks[t], i) whichever batch it runs in, so a share gives that share's episodes."""
        n = env_ids.shape[0]
        if episodes is None:
            env_state, obs0, info = adapter.reset(reset_keys, n)
        else:
            env_state, obs0, info = adapter.reset(reset_keys, n, episodes)
        run = scheduled if adapter.scheduler is not None else lockstep
        obs_seq, records, bad = run(
            actor_params, env_state, obs0, info, ks, env_ids, random_actions, deterministic, expert_envs
        )

        def with_reset(name):  # [N, T+1, .]: the reset observation first, then the T step observations
            return jnp.concatenate([obs0[name][:, None], obs_seq[name]], axis=1)

        episodes = {
            "z_obj": with_reset("z_obj"),
            "ee_xy": with_reset("ee_xy"),
            "obj_xy": with_reset("obj_xy"),
            "z_goal": info["z_goal"],
            "goal_xy": info["goal_xy"],
            "action": records["action"],
            "valid": ~bad,
            "demo": expert_envs,
        }
        if stored_priv_dim:
            episodes["priv"] = with_reset("priv")
        if "expert_action" in records:
            episodes["expert_action"] = records["expert_action"]
        return episodes

    return run_envs


def make_collect(config: TrainConfig, adapter: EnvAdapter, nets: Networks):
    """``collect`` for ``config``'s learner on ``adapter`` (see the module's docstring)."""
    run_envs = make_run_envs(config, adapter, nets)
    T = adapter.episode_len

    def collect(actor_params, key, num_envs: int, random_actions, deterministic, expert_envs, episodes=None):
        """One whole episode in ``num_envs`` envs -> (episode records [num_envs, ...], stats). Step t
        of environment i draws its randomness from fold_in(key_t, i), so an episode does not depend on
        how the environments were scheduled. ``episodes`` (``adapter.eval_episodes``) starts the
        protocol's episodes instead of freshly drawn ones where its ``use`` flag is True."""
        k_reset, k_roll = jax.random.split(key)
        expert_envs = jnp.broadcast_to(expert_envs, (num_envs,))
        eps = run_envs(
            actor_params,
            k_reset,
            jax.random.split(k_roll, T),
            jnp.arange(num_envs),
            random_actions,
            deterministic,
            expert_envs,
            episodes,
        )
        return eps, episode_stats(eps, adapter.success_tau)

    return collect


def device_layout(groups: tuple[int, ...], num_devices: int) -> np.ndarray:
    """The batch's environments in the order ``make_split_collect`` hands them to the devices: device d
    takes the d-th slice of every group, so each device's share is laid out like a batch of its own
    (its groups in the same order, each ``1 / num_devices`` of the size)."""
    if any(g % num_devices for g in groups):
        raise ConfigError(f"groups {groups} do not split evenly over {num_devices} devices")
    starts = np.cumsum((0,) + tuple(groups))[:-1]
    return np.concatenate(
        [
            start + d * (g // num_devices) + np.arange(g // num_devices)
            for d in range(num_devices)
            for start, g in zip(starts, groups)
        ]
    )


def make_split_collect(config: TrainConfig, one_device: EnvAdapter, nets: Networks, mesh, groups: tuple[int, ...]):
    """``collect`` (same arguments and results, the same episodes to float rounding) with a batch's
    environments split over ``mesh``'s devices (a 1-D mesh over axis ``mjx_push.devices.AXIS``), each
    device running its share's whole episodes as a batch of its own on ``one_device`` (the
    environment with every batch kept on one device; its ``reset`` takes per-environment keys).
    Splitting only the physics joins the devices at every tick of the rollout (which environments'
    steps ended, and the encoder and actor for them); a device running whole episodes waits for no
    other until its episodes end. ``groups`` is the batch's layout (``adapter.groups``)."""
    run_envs = make_run_envs(config, one_device, nets)
    T, D = one_device.episode_len, mesh.size
    order = device_layout(tuple(groups), D)
    back = np.argsort(order)
    env = P(devices.AXIS)

    def collect(actor_params, key, num_envs: int, random_actions, deterministic, expert_envs, episodes=None):
        if num_envs != len(order):
            raise ConfigError(f"this rollout is laid out for {len(order)} environments, got {num_envs}")
        k_reset, k_roll = jax.random.split(key)
        # The keys a one-device batch would give each environment (PushBatch.reset splits its key so).
        reset_keys = jax.random.split(k_reset, num_envs)[order]
        expert_envs = jnp.broadcast_to(expert_envs, (num_envs,))[order]
        args = (actor_params, reset_keys, jax.random.split(k_roll, T), jnp.asarray(order))
        args += (random_actions, deterministic, expert_envs)
        specs = (P(), env, P(), env, P(), P(), env)
        if episodes is not None:  # the evaluation episodes' fields per environment, their flag for all
            args += ({k: v if k == "use" else jax.tree.map(lambda x: x[order], v) for k, v in episodes.items()},)
            specs += ({k: P() if k == "use" else env for k in episodes},)
        run = jax.shard_map(run_envs, mesh=mesh, in_specs=specs, out_specs=env, check_vma=False)
        eps = run(*args)
        eps = jax.tree.map(lambda x: x[back], eps)
        return eps, episode_stats(eps, one_device.success_tau)

    return collect


def make_group_collect(config: TrainConfig, twins, nets: Networks, mesh, groups: tuple[int, ...]):
    """``collect`` (same arguments and results, the same episodes to float rounding) with each of the
    batch's contiguous groups (``adapter.groups``, the shape groups) run as a program of its own on
    its own ``mesh.size // len(groups)`` devices, ``twins[g]`` being group g's one-device environment
    (``adapter.one_device(adapter, g)``). Each program holds one shape's physics only, about half of
    what one program of both would; they are compiled, and run, from threads of their own, so on a
    CPU the groups' compilations share the cores instead of queueing on one. Not jittable (each
    program is); what it returns lies on the mesh's first device, where the learner runs."""
    G = len(groups)
    if len(twins) != G or mesh.size % G:
        raise ConfigError(f"{G} groups over {mesh.size} devices: each group needs devices of its own")
    T = twins[0].episode_len
    starts = np.cumsum((0,) + tuple(groups))[:-1]
    per_group = mesh.size // G
    home = jax.sharding.SingleDeviceSharding(mesh.devices.flat[0])
    runs = [make_run_envs(config, twin, nets) for twin in twins]
    meshes = [
        jax.sharding.Mesh(np.asarray(mesh.devices.flat[g * per_group : (g + 1) * per_group]), (devices.AXIS,))
        for g in range(G)
    ]
    programs: dict = {}

    def program(g: int, episode_fields: tuple[str, ...] | None):
        """Group g's compiled rollout (built once per kind of call: with evaluation episodes or not)."""
        if (g, episode_fields) not in programs:
            run = runs[g]  # one device per group (2 groups, 2 cores): the plain program, its arguments placed
            if per_group > 1:
                env = P(devices.AXIS)
                specs = (P(), env, P(), env, P(), P(), env)
                if episode_fields is not None:  # the evaluation episodes' fields per environment, their flag for all
                    specs += ({k: P() if k == "use" else env for k in episode_fields},)
                run = jax.shard_map(run, mesh=meshes[g], in_specs=specs, out_specs=env, check_vma=False)
            programs[g, episode_fields] = jax.jit(run)
        return programs[g, episode_fields]

    @jax.jit
    def join(parts):
        eps = jax.tree.map(lambda *xs: jnp.concatenate(xs), *parts)
        return eps, episode_stats(eps, twins[0].success_tau)

    def collect(actor_params, key, num_envs: int, random_actions, deterministic, expert_envs, episodes=None):
        if num_envs != sum(groups):
            raise ConfigError(f"this rollout is laid out for {sum(groups)} environments, got {num_envs}")
        if isinstance(key, jax.core.Tracer):
            raise ConfigError(
                "a rollout split into shape-group programs runs its compiled programs itself: call it "
                "unjitted (as Runner.rollout does), not inside jax.jit"
            )
        k_reset, k_roll = jax.random.split(key)
        # The keys a one-device batch would give each environment (PushBatch.reset splits its key so).
        reset_keys = jax.random.split(k_reset, num_envs)
        ks = jax.random.split(k_roll, T)
        expert_envs = jnp.broadcast_to(expert_envs, (num_envs,))
        env_ids = jnp.arange(num_envs)

        def run_group(g):
            sl = slice(int(starts[g]), int(starts[g]) + groups[g])
            everywhere = jax.sharding.NamedSharding(meshes[g], P())
            split = jax.sharding.NamedSharding(meshes[g], P(devices.AXIS))
            shared = jax.device_put((actor_params, ks, random_actions, deterministic), everywhere)
            own = jax.device_put((reset_keys[sl], env_ids[sl], expert_envs[sl]), split)
            args = (shared[0], own[0], shared[1], own[1], shared[2], shared[3], own[2])
            fields = None
            if episodes is not None:
                fields = tuple(episodes)
                share = {k: v if k == "use" else jax.tree.map(lambda x: x[sl], v) for k, v in episodes.items()}
                args += ({k: jax.device_put(v, everywhere if k == "use" else split) for k, v in share.items()},)
            return jax.block_until_ready(program(g, fields)(*args))

        parts = list(_pool(G).map(run_group, range(G)))
        return join(jax.device_put(parts, home))

    return collect


_POOLS: dict = {}


def _pool(n: int):
    """``n`` threads kept for the process, from which the groups' programs are compiled and run."""
    from concurrent.futures import ThreadPoolExecutor

    if n not in _POOLS:
        _POOLS[n] = ThreadPoolExecutor(n, thread_name_prefix="mjx-push-group")
    return _POOLS[n]

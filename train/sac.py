"""Soft actor-critic losses and update (docs/task.md section 6), following Stable-Baselines3's SAC.

One update, in SB3's order: the critic step (target from the target critics at s_{t+1} with a fresh
action from the current actor), then the actor step against the *updated* critics, then the entropy
coefficient step; all three use the entropy coefficient from before this update. Polyak averaging of
the target critics after every update. No terminal flags: episodes end by time limit, so the target
always bootstraps.

Batches come from ``mjx_push.train.replay.sample``: whole episodes plus the transition's step ``t``; networks
compute history features at t and t+1 with the (possibly relabelled) goal.

Options (``SACConfig``): ``target_clip`` clips TD targets to the return's range [-1/(1-gamma), 0];
``bc_weight`` adds behaviour cloning on a second batch of expert demonstration steps (never
relabelled), Q-filtered by default: the squared error between the actor's deterministic action and the
expert's counts only where the updated critics rate the expert's action higher. ``actor_loss`` "bc"
trains the actor on that term alone (cloning, DAgger-style with stored labels): its gradient never
reads the critics, which still learn (their losses stay comparable across learners).
"""

from __future__ import annotations

from typing import Any, Callable

import flax.struct
import jax
import jax.numpy as jnp
import optax

from mjx_push.train.config import AgentConfig, SACConfig
from mjx_push.train.data_parallel import flat_pmean
from mjx_push.train.networks import ACTION_DIM, Networks, make_networks
from mjx_push.errors import ConfigError

Params = Any


@flax.struct.dataclass
class SACState:
    actor_params: Params
    critic_params: Params
    target_critic_params: Params
    actor_opt_state: optax.OptState
    critic_opt_state: optax.OptState
    log_alpha: jax.Array
    alpha_opt_state: optax.OptState
    step: jax.Array  # int32: gradient updates done


# ---------------------------------------------------------------------------------------------------
# Loss arithmetic on plain values (what the hand-computed tests check).
# ---------------------------------------------------------------------------------------------------


def td_target(reward, next_q, next_logp, alpha, gamma):
    """r + gamma * (min_i Q_targ_i(s', a') - alpha * log pi(a'|s')); ``next_q`` is [2, B]."""
    return reward + gamma * (jnp.min(next_q, axis=0) - alpha * next_logp)


def critic_loss_value(q, target):
    """SB3's 0.5 * sum_i MSE(Q_i, target) over the twin critics; ``q`` is [2, B]."""
    return 0.5 * jnp.sum(jnp.mean((q - target[None]) ** 2, axis=-1))


def actor_loss_value(logp, q_pi, alpha):
    """mean(alpha * log pi(a|s) - min_i Q_i(s, a)), a ~ pi(.|s); ``q_pi`` is [2, B]."""
    return jnp.mean(alpha * logp - jnp.min(q_pi, axis=0))


def alpha_loss(log_alpha, logp, target_entropy):
    """SB3's automatic entropy loss: -mean(log_alpha * (log pi + target_entropy)), log pi held fixed."""
    return -jnp.mean(log_alpha * jax.lax.stop_gradient(logp + target_entropy))


# ---------------------------------------------------------------------------------------------------
# Loss factories over networks. ``nets`` needs ``policy(params, episode, idx, noise)`` and
# ``q(params, episode, idx, action)`` (see mjx_push.train.networks.Networks), so tests can pass stubs.
# ---------------------------------------------------------------------------------------------------


def _at(batch, offset):
    return (batch["t"] + offset)[:, None]  # [B, 1] step index for the networks


def make_critic_loss(nets: Networks, gamma: float, target_clip: bool = False) -> Callable:
    """``critic_loss(critic_params, target_critic_params, actor_params, alpha, batch, key, features=None)``:
    with ``features`` (``nets.actor_features`` of the batch under ``actor_params``) the next action is
    read from them instead of a pass of its own."""

    def critic_loss(critic_params, target_critic_params, actor_params, alpha, batch, key, features=None):
        B = batch["t"].shape[0]
        noise = jax.random.normal(key, (B, 1, nets.action_dim))
        if features is None:
            next_action, next_logp = nets.policy(actor_params, batch, _at(batch, 1), noise)
        else:
            next_action, next_logp, _ = nets.policy_from_features(actor_params, features, _at(batch, 1), noise)
        next_q = nets.q(target_critic_params, batch, _at(batch, 1), next_action)[..., 0]
        target = td_target(batch["reward"], next_q, next_logp[:, 0], alpha, gamma)
        if target_clip:  # rewards are -1 or 0, so every return lies in [-1/(1-gamma), 0]
            target = jnp.clip(target, -1.0 / (1.0 - gamma), 0.0)
        target = jax.lax.stop_gradient(target)
        q = nets.q(critic_params, batch, _at(batch, 0), batch["action"][:, None])[..., 0]
        return critic_loss_value(q, target), {"q": jnp.mean(q), "target_q": jnp.mean(target)}

    return critic_loss


def bc_loss_value(action, expert_action, keep):
    """Mean over the batch of ``keep`` * squared action error (summed over action dimensions)."""
    return jnp.mean(keep * jnp.sum((action - expert_action) ** 2, axis=-1))


def make_actor_loss(
    nets: Networks, bc_weight: float = 0.0, q_filter: bool = True, objective: str = "sac", anchor_weight: float = 0.0
) -> Callable:
    """``actor_loss(actor_params, critic_params, alpha, batch, key, demo=None, bc_scale=1.0, anchor=None,
    anchor_scale=None)``: SAC's actor loss plus ``bc_weight * bc_scale`` times the cloning term
    (``objective`` "sac"), or the cloning term alone ("bc"). ``bc_scale`` is the teacher's annealing
    factor (DemoConfig.teacher_scale). With ``anchor`` (frozen actor params) and ``anchor_weight`` > 0,
    plus ``anchor_weight * anchor_scale`` times the squared distance to the anchor's deterministic action
    on the batch's states (``anchor_scale`` defaults to ``1 - bc_scale``; DemoConfig.anchor_scale).
    With ``features`` (``nets.actor_features`` of the batch) the batch's actions come from them: the
    loss is then a function of the heads' parameters and of ``features``, and the gradient through the
    features is the caller's to add."""
    if objective not in ("sac", "bc"):
        raise ConfigError(f"actor objective must be 'sac' or 'bc', got {objective!r}")
    if objective == "bc" and (bc_weight <= 0 or q_filter):
        raise ConfigError("the cloning-only actor needs bc_weight > 0 and no Q-filter")

    def actor_loss(
        actor_params,
        critic_params,
        alpha,
        batch,
        key,
        demo=None,
        bc_scale=1.0,
        anchor=None,
        anchor_scale=None,
        features=None,
    ):
        B = batch["t"].shape[0]
        noise = jax.random.normal(key, (B, 1, nets.action_dim))
        if features is None:
            action, logp, mode = nets.policy_with_mode(actor_params, batch, _at(batch, 0), noise)
        else:  # the heads on given features: the caller carries their gradient back (`make_update`)
            action, logp, mode = nets.policy_from_features(actor_params, features, _at(batch, 0), noise)
        logp = logp[:, 0]
        aux = {"logp": logp}
        if objective == "bc":
            loss = jnp.zeros(())  # the critics are not read at all (no Q term, no entropy term)
        else:
            q_pi = nets.q(critic_params, batch, _at(batch, 0), action)[..., 0]
            loss = actor_loss_value(logp, q_pi, alpha)
        if demo is not None and bc_weight > 0:

            def cloning():
                pi = nets.deterministic_action(actor_params, demo, _at(demo, 0))[:, 0]
                expert = demo.get("expert_action", demo["action"])  # the noise-free label when stored
                if q_filter:  # clone only where the critics prefer the expert's action to the actor's
                    q_e = jnp.min(nets.q(critic_params, demo, _at(demo, 0), expert[:, None]), axis=0)[:, 0]
                    held = jax.lax.stop_gradient(pi)[:, None]
                    q_a = jnp.min(nets.q(critic_params, demo, _at(demo, 0), held), axis=0)[:, 0]
                    keep = jax.lax.stop_gradient((q_e > q_a).astype(jnp.float32))
                else:
                    keep = jnp.ones(pi.shape[:1])
                return bc_loss_value(pi, expert, keep), jnp.mean(keep)

            # Once the teacher has gone its term weighs nothing: its forward and backward passes are
            # skipped (its metrics then read 0).
            bc, kept = jax.lax.cond(jnp.asarray(bc_scale) > 0, cloning, lambda: (jnp.zeros(()), jnp.zeros(())))
            loss = loss + bc_weight * bc_scale * bc
            aux.update(bc_loss=bc, bc_kept=kept, bc_scale=jnp.asarray(bc_scale, jnp.float32))
        if anchor is not None and anchor_weight > 0:
            held_by = jnp.asarray(1.0 - bc_scale if anchor_scale is None else anchor_scale, jnp.float32)
            mine = mode[:, 0]

            def drift_from_anchor():
                held = jax.lax.stop_gradient(nets.deterministic_action(anchor, batch, _at(batch, 0))[:, 0])
                return bc_loss_value(mine, held, jnp.ones(mine.shape[:1]))

            # Skipped while the anchor weighs nothing (before the teacher leaves, after its release).
            drift = jax.lax.cond(held_by > 0, drift_from_anchor, lambda: jnp.zeros(()))
            loss = loss + anchor_weight * held_by * drift
            aux.update(anchor_drift=drift, anchor_scale=held_by)
        return loss, aux

    return actor_loss


# ---------------------------------------------------------------------------------------------------
# Optimiser, state, update.
# ---------------------------------------------------------------------------------------------------


def make_optimizer(sac: SACConfig, total_updates: int | None = None) -> optax.GradientTransformation:
    """Adam; with ``sac.lr_decay`` the rate falls linearly from ``sac.lr`` to 0 over ``total_updates``."""
    if not sac.lr_decay:
        return optax.adam(sac.lr)
    if not total_updates or total_updates < 1:
        raise ConfigError(f"sac.lr_decay needs total_updates >= 1, got {total_updates!r}")
    return optax.adam(optax.linear_schedule(sac.lr, 0.0, total_updates))


def polyak(online, target, tau):
    return jax.tree.map(lambda o, t: tau * o + (1.0 - tau) * t, online, target)


def init_state(
    key: jax.Array, nets: Networks, sac: SACConfig, episode_len: int, total_updates: int | None = None
) -> SACState:
    actor_params, critic_params = nets.init(key, episode_len)
    opt = make_optimizer(sac, total_updates)
    log_alpha = jnp.asarray(jnp.log(sac.init_alpha), jnp.float32)
    return SACState(
        actor_params=actor_params,
        critic_params=critic_params,
        # A copy, not an alias: the loop donates the state, and XLA rejects one buffer donated twice.
        target_critic_params=jax.tree.map(jnp.copy, critic_params),
        actor_opt_state=opt.init(actor_params),
        critic_opt_state=opt.init(critic_params),
        log_alpha=log_alpha,
        alpha_opt_state=opt.init(log_alpha),
        step=jnp.zeros((), jnp.int32),
    )


def make_update(
    agent: AgentConfig,
    sac: SACConfig,
    action_dim: int = ACTION_DIM,
    total_updates: int | None = None,
    nets: Networks | None = None,
    axis_name: str | None = None,
    share_actor_pass: bool = True,
) -> Callable[[SACState, dict, jax.Array], tuple[SACState, dict]]:
    """``update(state, batch, key) -> (state, metrics)``, one SAC gradient step (pure, jittable).

    ``share_actor_pass``: the actor's extractor runs once over the batch for the critic's target and
    the actor's loss (the same parameters, the same episodes), its gradient carried back by a VJP; the
    same step as two passes, up to float rounding, and for uGRU and eGRU one GRU pass fewer per update.

    With ``axis_name`` (data-parallel training, train/data_parallel.py) the gradients are averaged
    over that mapped axis before they are used, so each device's batch is one shard of the step's batch
    and every device applies the same step to the same parameters. Two all-reduces per update, each
    of one flat vector (the critics' gradients; the actor's with the entropy coefficient's), since
    across processes every collective costs a round trip; the metrics stay per device."""
    nets = nets if nets is not None else make_networks(agent, action_dim)
    opt = make_optimizer(sac, total_updates)
    critic_loss = jax.value_and_grad(make_critic_loss(nets, sac.gamma, sac.target_clip), has_aux=True)
    actor_loss_fn = make_actor_loss(nets, sac.bc_weight, sac.q_filter, sac.actor_loss, sac.anchor_weight)
    actor_loss = jax.value_and_grad(actor_loss_fn, has_aux=True)
    # With the shared pass: the gradient w.r.t. the parameters the heads read, and w.r.t. the features.
    actor_loss_on_features = jax.value_and_grad(actor_loss_fn, argnums=(0, 9), has_aux=True)
    alpha_grad = jax.value_and_grad(alpha_loss)
    target_entropy = sac.resolved_target_entropy(action_dim)

    def mean(tree):
        return tree if axis_name is None else flat_pmean(tree, axis_name)

    def step(params, opt_state, grads):
        updates, opt_state = opt.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state

    def update(
        state: SACState,
        batch: dict,
        key: jax.Array,
        demo: dict | None = None,
        bc_scale=1.0,
        anchor=None,
        anchor_scale=None,
    ) -> tuple[SACState, dict]:
        """One update; ``demo`` is a batch of demonstration steps for the behaviour-cloning term, whose
        weight ``bc_scale`` multiplies (the teacher's annealing); ``anchor`` the frozen actor params the
        actor is held to as the teacher goes (SACConfig.anchor_weight), with ``anchor_scale`` on its
        weight (default ``1 - bc_scale``)."""
        k_next, k_pi = jax.random.split(key)
        alpha = jnp.exp(state.log_alpha)  # this update's coefficient, fixed before the alpha step

        features = pull_back = None
        if share_actor_pass:
            # One pass of the actor's extractor over the batch's episodes serves the critic's target
            # (step t+1) and the actor's loss (step t): both read the actor before this update.
            features, pull_back = jax.vjp(lambda p: nets.actor_features(p, batch), state.actor_params)
        (c_loss, c_aux), c_grads = critic_loss(
            state.critic_params, state.target_critic_params, state.actor_params, alpha, batch, k_next, features
        )
        critic_params, critic_opt_state = step(state.critic_params, state.critic_opt_state, mean(c_grads))

        actor_args = (state.actor_params, critic_params, alpha, batch, k_pi, demo, bc_scale, anchor, anchor_scale)
        if share_actor_pass:
            (a_loss, a_aux), (a_grads, feature_grads) = actor_loss_on_features(*actor_args, features)
            # the chain rule's other half: through the features back to the extractor's parameters
            a_grads = jax.tree.map(jnp.add, a_grads, pull_back(feature_grads)[0])
        else:
            (a_loss, a_aux), a_grads = actor_loss(*actor_args)
        logp = a_aux["logp"]
        al_loss, al_grad = alpha_grad(state.log_alpha, logp, target_entropy)
        a_grads, al_grad = mean((a_grads, al_grad))
        actor_params, actor_opt_state = step(state.actor_params, state.actor_opt_state, a_grads)
        log_alpha, alpha_opt_state = step(state.log_alpha, state.alpha_opt_state, al_grad)

        new_state = SACState(
            actor_params=actor_params,
            critic_params=critic_params,
            target_critic_params=polyak(critic_params, state.target_critic_params, sac.tau),
            actor_opt_state=actor_opt_state,
            critic_opt_state=critic_opt_state,
            log_alpha=log_alpha,
            alpha_opt_state=alpha_opt_state,
            step=state.step + 1,
        )
        metrics = {
            "critic_loss": c_loss,
            "actor_loss": a_loss,
            "alpha_loss": al_loss,
            "alpha": alpha,
            "entropy": -jnp.mean(logp),
            "q": c_aux["q"],
            "target_q": c_aux["target_q"],
            "reward": jnp.mean(batch["reward"]),
            **{k: v for k, v in a_aux.items() if k != "logp"},
        }
        return new_state, metrics

    return update

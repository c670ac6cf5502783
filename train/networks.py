"""Actor and twin critic for VPM, Stacked and GRU agents (docs/task.md section 6), in flax.linen.

Two views of the same networks:

* whole-episode (learner): inputs are episode histories ``ee_xy [B, L, 2]``, ``z_obj [B, L, 6]``,
  ``z_goal [B, 6]`` and step indices ``idx [B, K]``; the extractor computes features for every step in
  one pass and the MLP heads run only at the requested steps. After HER relabelling the learner asks for
  steps t and t+1 with the new goal, so every GRU hidden state is recomputed with that goal.
* online (rollouts): ``init_carry`` / ``act`` consume one observation per step and carry the extractor's
  memory (GRU hidden state, the last ``stack`` observations, or nothing for VPM). Both views run the
  same parameters through the same cell, so they give the same actions (up to float rounding: XLA may
  order the arithmetic differently for the two shapes; the tests allow 1e-6).

Observation per step: ``ee_xy (2)``, ``z_obj (6)``, ``z_goal (6)``; flat order [ee_xy, z_obj, z_goal].
The GRU input per step is [z_obj_t, z_goal, ee_xy_t] (docs/task.md section 6; exported weights assume it).

Options (``AgentConfig``): with ``obs_norm`` every network first standardises its inputs with running
statistics held in its variables' "norm" collection (``ee_xy`` and the latent ``z``, shared by the
object and goal codes; the privileged critic's ``priv`` and ``goal``); the learner writes them after
every batch and gradients never reach them. With ``critic_obs="privileged"`` the critics are MLPs over
the episode's ground-truth state ``priv [B, L, P]`` at the step (its first two numbers are the object's
xy, the achieved goal) and the goal ``goal_xy [B, 2]``; the actor never sees either.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from mjx_push.train.config import AgentConfig
from mjx_push.errors import ConfigError

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0
OBS_DIM = 14
ACTION_DIM = 3

Params = Any


def _goal_like(z_goal: jax.Array, z_obj: jax.Array) -> jax.Array:
    # The goal is constant over an episode, so with a time axis it comes without one: broadcast it.
    if z_goal.ndim < z_obj.ndim:
        z_goal = jnp.expand_dims(z_goal, -2)
    return jnp.broadcast_to(z_goal, z_obj.shape[:-1] + z_goal.shape[-1:])


def flat_obs(ee_xy: jax.Array, z_obj: jax.Array, z_goal: jax.Array) -> jax.Array:
    """[..., 14] = [ee_xy, z_obj, z_goal]."""
    return jnp.concatenate([ee_xy, z_obj, _goal_like(z_goal, z_obj)], axis=-1)


def gru_input(ee_xy: jax.Array, z_obj: jax.Array, z_goal: jax.Array) -> jax.Array:
    """[..., 14] = [z_obj, z_goal, ee_xy], the GRU's input order."""
    return jnp.concatenate([z_obj, _goal_like(z_goal, z_obj), ee_xy], axis=-1)


# ----------------------------------------------------------------------------------------------------
# Feature extractors. Each has  __call__(ee [B,L,2], z_obj [B,L,6], z_goal [B,6]) -> [B, L, F]  (all
# steps, causal) and  step(carry, ee [B,2], z_obj [B,6], z_goal [B,6]) -> (carry, [B, F]).
# ----------------------------------------------------------------------------------------------------


class VPMFeatures(nn.Module):
    """The current 14-number observation."""

    def __call__(self, ee_xy, z_obj, z_goal):
        return flat_obs(ee_xy, z_obj, z_goal)

    def step(self, carry, ee_xy, z_obj, z_goal):
        return carry, flat_obs(ee_xy, z_obj, z_goal)

    def initial_carry(self, batch: int) -> jax.Array:
        return jnp.zeros((batch, 0), jnp.float32)  # no memory; an empty array keeps scan carries uniform


class StackedFeatures(nn.Module):
    """The last ``stack`` observations, oldest first, zero-padded before step 0 (like frame stacking)."""

    stack: int = 5

    def __call__(self, ee_xy, z_obj, z_goal):
        x = flat_obs(ee_xy, z_obj, z_goal)  # [B, L, 14]
        length = x.shape[1]
        padded = jnp.pad(x, ((0, 0), (self.stack - 1, 0), (0, 0)))
        # Window for step t is padded[t : t + stack]; slicing per offset keeps it causal and cheap.
        return jnp.concatenate([padded[:, j : j + length] for j in range(self.stack)], axis=-1)

    def step(self, carry, ee_xy, z_obj, z_goal):
        x = flat_obs(ee_xy, z_obj, z_goal)
        carry = jnp.concatenate([carry[:, 1:], x[:, None]], axis=1)  # drop the oldest, append the newest
        return carry, carry.reshape(carry.shape[0], -1)

    def initial_carry(self, batch: int) -> jax.Array:
        return jnp.zeros((batch, self.stack, OBS_DIM), jnp.float32)


class GRUFeatures(nn.Module):
    """GRU over the episode history (h0 = 0); the feature at step t is the hidden state after step t."""

    hidden: int = 32

    def setup(self):
        # One scanned cell serves both views: the online step is a scan of length 1, so it runs the
        # very same parameters and ops as the whole-episode scan.
        self.cell = nn.scan(
            nn.GRUCell,
            variable_broadcast="params",
            split_rngs={"params": False},
            in_axes=1,
            out_axes=1,
        )(features=self.hidden)

    def __call__(self, ee_xy, z_obj, z_goal):
        x = gru_input(ee_xy, z_obj, z_goal)  # [B, L, 14]
        h0 = jnp.zeros((x.shape[0], self.hidden), x.dtype)
        _, hs = self.cell(h0, x)
        return hs

    def step(self, carry, ee_xy, z_obj, z_goal):
        h, _ = self.cell(carry, gru_input(ee_xy, z_obj, z_goal)[:, None])
        return h, h

    def initial_carry(self, batch: int) -> jax.Array:
        return jnp.zeros((batch, self.hidden), jnp.float32)


def make_extractor(agent: AgentConfig, name: str | None = None) -> nn.Module:
    if agent.kind == "vpm":
        return VPMFeatures(name=name)
    if agent.kind == "stacked":
        return StackedFeatures(stack=agent.stack, name=name)
    return GRUFeatures(hidden=agent.gru_hidden, name=name)


def take_steps(features: jax.Array, idx: jax.Array) -> jax.Array:
    """features [B, L, F], idx [B, K] -> [B, K, F]."""
    return jnp.take_along_axis(features, idx[..., None], axis=1)


class MLP(nn.Module):
    hidden: Sequence[int]
    layer_norm: bool = False

    @nn.compact
    def __call__(self, x):
        for h in self.hidden:
            x = nn.Dense(h)(x)
            if self.layer_norm:
                x = nn.LayerNorm()(x)
            x = nn.relu(x)
        return x


# Input groups standardised by each network when obs_norm is on (name -> width).
ACTOR_NORM_GROUPS = {"ee_xy": 2, "z": 6}
NORM_MIN_STD = 1e-3


def critic_norm_groups(critic_obs: str, priv_dim: int) -> dict[str, int]:
    return {"priv": priv_dim, "goal": 2} if critic_obs == "privileged" else dict(ACTOR_NORM_GROUPS)


class Normalizer(nn.Module):
    """(x - mean) / std, clipped, per named input group; identity when ``groups`` is empty. The
    statistics are variables of collection "norm" (mean 0, std 1 at init) that the learner overwrites;
    stop_gradient keeps the optimiser's hands off them (their Adam updates are exactly zero)."""

    groups: dict
    clip: float = 5.0

    def setup(self):
        self.stats = {
            name: (
                self.variable("norm", f"{name}_mean", jnp.zeros, (dim,)),
                self.variable("norm", f"{name}_std", jnp.ones, (dim,)),
            )
            for name, dim in self.groups.items()
        }

    def __call__(self, name: str, x: jax.Array) -> jax.Array:
        if name not in self.stats:
            return x
        mean, std = (jax.lax.stop_gradient(v.value) for v in self.stats[name])
        return jnp.clip((x - mean) / std, -self.clip, self.clip)


def normalize_inputs(norm: Normalizer, ee_xy, z_obj, z_goal):
    return norm("ee_xy", ee_xy), norm("z", z_obj), norm("z", z_goal)


class Actor(nn.Module):
    agent: AgentConfig
    action_dim: int = ACTION_DIM

    def setup(self):
        self.norm = Normalizer(ACTOR_NORM_GROUPS if self.agent.obs_norm else {}, self.agent.norm_clip)
        self.features = make_extractor(self.agent)
        self.mlp = MLP(self.agent.hidden)
        self.mean_head = nn.Dense(self.action_dim)
        self.log_std_head = nn.Dense(self.action_dim)

    def head(self, feat):
        h = self.mlp(feat)
        return self.mean_head(h), jnp.clip(self.log_std_head(h), LOG_STD_MIN, LOG_STD_MAX)

    def __call__(self, ee_xy, z_obj, z_goal, idx):
        """Gaussian parameters (mean, log_std) [B, K, A] at steps idx [B, K] of the episodes."""
        return self.head_at(self.episode_features(ee_xy, z_obj, z_goal), idx)

    def episode_features(self, ee_xy, z_obj, z_goal):
        """The extractor's features [B, L, F] at every step of the episodes (inputs normalised)."""
        return self.features(*normalize_inputs(self.norm, ee_xy, z_obj, z_goal))

    def head_at(self, features, idx):
        """Gaussian parameters at steps idx [B, K] of ``episode_features``' output."""
        return self.head(take_steps(features, idx))

    def step(self, carry, ee_xy, z_obj, z_goal):
        carry, feat = self.features.step(carry, *normalize_inputs(self.norm, ee_xy, z_obj, z_goal))
        return carry, self.head(feat)


class QNetwork(nn.Module):
    """Q over the actor's observation history (the paper's critic)."""

    agent: AgentConfig

    @nn.compact
    def __call__(self, episode, idx, action):
        """Q [B, K] of ``action [B, K, A]`` at steps idx [B, K]."""
        norm = Normalizer(ACTOR_NORM_GROUPS if self.agent.obs_norm else {}, self.agent.norm_clip, name="norm")
        x = normalize_inputs(norm, episode["ee_xy"], episode["z_obj"], episode["z_goal"])
        feat = take_steps(make_extractor(self.agent, name="features")(*x), idx)
        h = MLP(self.agent.critic_widths, self.agent.critic_layer_norm, name="mlp")(jnp.concatenate([feat, action], -1))
        return nn.Dense(1, name="q_head")(h)[..., 0]


class PrivilegedQNetwork(nn.Module):
    """Q over the simulator's ground truth at the step and the goal (asymmetric actor-critic): the
    state is Markov, so no history is needed."""

    agent: AgentConfig
    priv_dim: int

    @nn.compact
    def __call__(self, episode, idx, action):
        norm = Normalizer(
            critic_norm_groups(self.agent.critic_obs, self.priv_dim) if self.agent.obs_norm else {},
            self.agent.norm_clip,
            name="norm",
        )
        priv = take_steps(episode["priv"], idx)  # [B, K, P]
        goal = jnp.broadcast_to(episode["goal_xy"][:, None], priv.shape[:-1] + (2,))
        # The goal relative to the achieved goal (priv's first two numbers), in metres: the distance
        # that decides the reward, given directly rather than left for the MLP to subtract.
        x = jnp.concatenate([norm("priv", priv), norm("goal", goal), (goal - priv[..., :2]) * 10.0, action], -1)
        h = MLP(self.agent.critic_widths, self.agent.critic_layer_norm, name="mlp")(x)
        return nn.Dense(1, name="q_head")(h)[..., 0]


def _twin(module):
    # Twin critics: two independent Q networks stored with a leading axis of 2 and evaluated in one
    # vectorised pass (their normalisation statistics are stacked too and kept equal).
    return nn.vmap(
        module,
        variable_axes={"params": 0, "norm": 0},
        split_rngs={"params": True},
        in_axes=None,
        out_axes=0,
        axis_size=2,
    )


TwinQ = _twin(QNetwork)
TwinPrivilegedQ = _twin(PrivilegedQNetwork)


def squash(mean: jax.Array, log_std: jax.Array, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
    """tanh-squashed Gaussian sample a = tanh(mean + std * noise) and its log-density.

    log p(a) = log N(u; mean, std) - sum log(1 - tanh(u)^2), with the Jacobian term in the stable form
    log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)) (no epsilon, exact also where tanh saturates).
    """
    u = mean + jnp.exp(log_std) * noise
    gauss = -0.5 * noise**2 - log_std - 0.5 * math.log(2.0 * math.pi)
    log_det = 2.0 * (math.log(2.0) - u - jax.nn.softplus(-2.0 * u))
    return jnp.tanh(u), jnp.sum(gauss - log_det, axis=-1)


@dataclasses.dataclass(frozen=True)
class Networks:
    """Pure functions over explicit parameters for one agent kind.

    ``episode`` is a mapping with ``ee_xy [B, L, 2]``, ``z_obj [B, L, 6]``, ``z_goal [B, 6]``.
    """

    agent: AgentConfig
    action_dim: int = ACTION_DIM
    priv_dim: int = 0  # width of the ground-truth state the privileged critic reads

    @property
    def actor(self) -> Actor:
        return Actor(self.agent, self.action_dim)

    @property
    def critic(self) -> nn.Module:
        if self.agent.critic_obs == "privileged":
            if self.priv_dim < 2:  # only the learner builds critics; policies and exports need the actor alone
                raise ConfigError(
                    "agent.critic_obs 'privileged' needs an environment that reports its ground-truth "
                    f"state (priv_dim >= 2, got {self.priv_dim})"
                )
            return TwinPrivilegedQ(self.agent, self.priv_dim)
        return TwinQ(self.agent)

    def dummy_episode(self, episode_len: int) -> dict:
        L = episode_len + 1
        ep = {
            "ee_xy": jnp.zeros((1, L, 2)),
            "z_obj": jnp.zeros((1, L, 6)),
            "z_goal": jnp.zeros((1, 6)),
            "goal_xy": jnp.zeros((1, 2)),
        }
        if self.priv_dim:
            ep["priv"] = jnp.zeros((1, L, self.priv_dim))
        return ep

    def init(self, key: jax.Array, episode_len: int) -> tuple[Params, Params]:
        """(actor_params, critic_params) for episodes of ``episode_len`` steps (``episode_len + 1`` obs)."""
        ka, kc = jax.random.split(key)
        ep = self.dummy_episode(episode_len)
        idx = jnp.zeros((1, 1), jnp.int32)
        critic = self.critic.init(kc, ep, idx, jnp.zeros((1, 1, self.action_dim)))
        return self.init_actor(ka, episode_len), critic

    def init_actor(self, key: jax.Array, episode_len: int) -> Params:
        """The actor's variables alone (what saved and exported policies hold)."""
        ep = self.dummy_episode(episode_len)
        return self.actor.init(key, ep["ee_xy"], ep["z_obj"], ep["z_goal"], jnp.zeros((1, 1), jnp.int32))

    def policy(self, actor_params, episode, idx, noise) -> tuple[jax.Array, jax.Array]:
        """Actions [B, K, A] and log-probs [B, K] at steps idx [B, K]; ``noise [B, K, A]`` is the
        standard-normal draw (zeros give the deterministic action tanh(mean))."""
        mean, log_std = self.actor.apply(actor_params, episode["ee_xy"], episode["z_obj"], episode["z_goal"], idx)
        return squash(mean, log_std, noise)

    def policy_with_mode(self, actor_params, episode, idx, noise) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``policy``'s actions and log-probs, and the deterministic action tanh(mean) [B, K, A] of the
        same forward pass (the actor loss needs both: a second pass through a GRU costs as much)."""
        return self.policy_from_features(actor_params, self.actor_features(actor_params, episode), idx, noise)

    def actor_features(self, actor_params, episode) -> jax.Array:
        """The actor's features [B, L, F] at every step of the episodes: the part of its forward pass
        (the GRU over the history, for uGRU and eGRU) that ``policy_from_features`` reads at any steps,
        so one pass serves the critic's target (step t+1) and the actor's loss (step t)."""
        return self.actor.apply(
            actor_params, episode["ee_xy"], episode["z_obj"], episode["z_goal"], method=Actor.episode_features
        )

    def policy_from_features(self, actor_params, features, idx, noise) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``policy_with_mode`` at steps idx from ``actor_features``' output (the heads alone)."""
        mean, log_std = self.actor.apply(actor_params, features, idx, method=Actor.head_at)
        action, logp = squash(mean, log_std, noise)
        return action, logp, jnp.tanh(mean)

    def q(self, critic_params, episode, idx, action) -> jax.Array:
        """Twin Q values [2, B, K]."""
        return self.critic.apply(critic_params, episode, idx, action)

    def deterministic_action(self, actor_params, episode, idx) -> jax.Array:
        """tanh(mean) [B, K, A] at steps idx (what evaluation and export run)."""
        mean, _ = self.actor.apply(actor_params, episode["ee_xy"], episode["z_obj"], episode["z_goal"], idx)
        return jnp.tanh(mean)

    def init_carry(self, batch: int) -> jax.Array:
        return make_extractor(self.agent).initial_carry(batch)

    def act(self, actor_params, carry, obs_step, key, deterministic) -> tuple[jax.Array, jax.Array]:
        """One online step: ``obs_step`` holds ``ee_xy [N, 2]``, ``z_obj [N, 6]``, ``z_goal [N, 6]``.
        ``key`` is one key for the batch or one per environment ([N, 2]: each environment's noise then
        depends on its own key only, whatever the batch). ``deterministic`` may be a traced bool."""
        carry, (mean, log_std) = self.actor.apply(
            actor_params, carry, obs_step["ee_xy"], obs_step["z_obj"], obs_step["z_goal"], method=Actor.step
        )
        if key.ndim == 2:
            noise = jax.vmap(lambda k: jax.random.normal(k, mean.shape[1:], mean.dtype))(key)
        else:
            noise = jax.random.normal(key, mean.shape, mean.dtype)
        noise = jnp.where(deterministic, jnp.zeros_like(noise), noise)
        action, _ = squash(mean, log_std, noise)
        return action, carry


def make_networks(agent: AgentConfig, action_dim: int = ACTION_DIM, priv_dim: int = 0) -> Networks:
    return Networks(agent, action_dim, priv_dim)

"""The learner's view of an environment: ``EnvAdapter``, pure functions over batches of environments.

The learner (train/loop.py, train/rollout.py) sees an environment only through it, so the same code
runs the toy task of the tests (tests/toy.py) and the MJX pushing scene (train/push_task.py):

* ``reset(key, num_envs) -> (env_state, step_obs, episode_info)``, ``step_obs`` = {``ee_xy [N, 2]``,
  ``z_obj [N, 6]``, ``obj_xy [N, 2]``} (+ ``priv [N, priv_dim]``), ``episode_info`` = {``z_goal [N, 6]``,
  ``goal_xy [N, 2]``};
* ``step(env_state, action [N, 3] in [-1, 1]) -> (env_state, step_obs, invalid [N] bool)``. An
  episode with any invalid step is stored with ``valid=False`` and never sampled;
* ``success_tau`` and ``episode_len``, the task's success radius (metres) and episode length (steps):
  the learner's rewards, relabelled or not, and its episodes follow them (the learner has no copies);
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
from typing import Any, Callable

import jax
import jax.numpy as jnp
from mjx_push.errors import ConfigError


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
            raise ConfigError(f"substep chunk must be a positive integer, got {self.chunk!r}")


@dataclasses.dataclass(frozen=True)
class EnvAdapter:
    reset: Callable[[jax.Array, int], tuple[Any, dict, dict]]
    step: Callable[[Any, jax.Array], tuple[Any, dict, jax.Array]]
    # The task's facts, the environment's: its success radius (the learner's rewards, relabelled or not,
    # are the task's sparse reward at it) and its episode length (the steps of every episode collected).
    success_tau: float
    episode_len: int
    # When set, rollouts step the environments asynchronously through it, faster; every random draw is
    # keyed by environment and step, so the episodes are ``step``'s up to float rounding, which an
    # integer substep count can grow within a few steps (the same for any chunk).
    scheduler: SubstepScheduler | None = None
    priv_dim: int = 0
    expert: Callable[[dict, dict], jax.Array] | None = None
    # The devices a batch of ``num_envs`` environments is split over (a jax Mesh), or None for one.
    mesh: Callable[[int], Any] | None = None
    # ``one_device(adapter, group=None)``: the same environment with every batch on one device, whose
    # ``reset`` also takes the environments' own keys [N, 2] (those ``jax.random.split(key, N)``
    # gives), or None when ``adapter`` is not the one that made it (a copy with a function replaced:
    # its twin would drop the change). With ``group`` (an index into ``groups``) only that group's
    # environments, as a batch of their own. With it the rollout splits a batch over ``mesh`` by whole
    # episodes: one program per group on its own devices (``mjx_push.train.rollout.make_group_collect``)
    # or each device running its share of every group (``make_split_collect``).
    one_device: Callable[..., "EnvAdapter | None"] | None = None
    groups: Callable[[int], tuple[int, ...]] | None = None
    eval_episodes: Callable[[str, int, int, int], dict] | None = None

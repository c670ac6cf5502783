"""A tiny goal-reaching task behind the same ``EnvAdapter`` as the MJX pushing environment.

A point "object" in the plane moves directly with the action: obj_xy += step_size * action[:2],
clipped to the box [-bound, bound]^2 (a_s is ignored). The end effector sits on the object. The
object and goal are observed only through a fixed random linear map into 6 latent dimensions (seeded),
so, as with the real encoder, the agent must read the goal through a latent code. Start and goal are
uniform in the box. It exercises the whole SAC + HER pipeline in seconds on a CPU.
"""

from __future__ import annotations

import flax.struct
import jax
import jax.numpy as jnp

from train.loop import EnvAdapter


@flax.struct.dataclass
class ToyState:
    obj_xy: jax.Array  # [N, 2]
    key: jax.Array  # drives the optional random invalid flags


def latent_map(seed: int, bound: float) -> jax.Array:
    """[2, 6] matrix with z = xy @ M; scaled so latent codes are O(1), like an encoder's."""
    return jax.random.normal(jax.random.PRNGKey(seed), (2, 6)) / bound


def make_toy(
    success_tau: float = 0.025,
    step_size: float = 0.05,
    bound: float = 0.15,
    seed: int = 0,
    invalid_prob: float = 0.0,
) -> EnvAdapter:
    """The toy adapter. ``success_tau`` is the task's success radius; the learner computes rewards
    from ``obj_xy`` / ``goal_xy`` with ``ReplayConfig.success_tau``, and ``make_train`` checks that the
    two agree. ``invalid_prob`` flags random steps invalid, to exercise the handling of broken
    simulations. A larger tolerance than the real task's 1 cm keeps learning fast in tests."""
    M = latent_map(seed, bound)

    def observe(obj_xy):
        return {"ee_xy": obj_xy, "z_obj": obj_xy @ M, "obj_xy": obj_xy}

    def reset(key, num_envs):
        k_obj, k_goal, k_state = jax.random.split(key, 3)
        obj = jax.random.uniform(k_obj, (num_envs, 2), minval=-bound, maxval=bound)
        goal = jax.random.uniform(k_goal, (num_envs, 2), minval=-bound, maxval=bound)
        return ToyState(obj, k_state), observe(obj), {"z_goal": goal @ M, "goal_xy": goal}

    def step(state, action):
        obj = jnp.clip(state.obj_xy + step_size * jnp.clip(action[:, :2], -1.0, 1.0), -bound, bound)
        key, k_bad = jax.random.split(state.key)
        invalid = jax.random.uniform(k_bad, (obj.shape[0],)) < invalid_prob
        return ToyState(obj, key), observe(obj), invalid

    return EnvAdapter(reset=reset, step=step, success_tau=success_tau)

"""The MJX pushing environment behind the learner's `EnvAdapter`: masks in, latents out.

Each environment step's object mask is encoded once, here, on device; the goal mask once per episode.
The learner (and its replay buffer) only ever sees the 6-number latents, the noisy flange xy, and the
ground-truth object and goal xy that rewards and HER relabelling need. An environment whose episode
went invalid (NaN, object through or off the table) reports it through `episode_invalid`; the learner
stores that episode as invalid and never samples it (SPEC section 8).
"""

from __future__ import annotations

import jax

from mjx_push import encoder as enc
from mjx_push.batch import BatchState, PushBatch
from mjx_push.env import EnvConfig
from train.loop import EnvAdapter, SubstepScheduler


# Substeps per scheduler tick: each environment takes its next action as soon as its own step's a_s
# substeps are spent, instead of every step waiting for the slowest environment
# (benchmarks/rollout_throughput.py measures the effect of this value).
DEFAULT_SUBSTEP_CHUNK = 50


def make_push_adapter(env_config: EnvConfig, encoder_params, substep_chunk: int = DEFAULT_SUBSTEP_CHUNK) -> EnvAdapter:
    """Adapter over `PushBatch(env_config, n)`; one batch object is built per environment count `n`.
    `substep_chunk` 0 steps all environments in lockstep; both give the same episodes."""
    if not (isinstance(substep_chunk, int) and substep_chunk >= 0):
        raise ValueError(f"substep_chunk must be an integer >= 0 (0: lockstep), got {substep_chunk!r}")
    batches: dict[int, PushBatch] = {}

    def batch(n: int) -> PushBatch:
        if n not in batches:
            batches[n] = PushBatch(env_config, n)
        return batches[n]

    def observe(s: BatchState) -> dict:
        obs = s.obs
        return {"ee_xy": obs["ee_xy"], "z_obj": enc.encode(encoder_params, obs["object_mask"]),
                "obj_xy": s.info("object_xy")}

    def reset(key: jax.Array, num_envs: int):
        s = batch(num_envs).reset(key)
        info = {"z_goal": enc.encode(encoder_params, s.obs["goal_mask"]), "goal_xy": s.info("goal_xy")}
        return s, observe(s), info

    def step(s: BatchState, action: jax.Array):
        s = batch(action.shape[0]).step(s, action)
        return s, observe(s), s.info("episode_invalid")

    def begin(s: BatchState, action: jax.Array, mask: jax.Array) -> BatchState:
        return batch(action.shape[0]).begin(s, action, mask)

    def advance(s: BatchState, max_substeps: int) -> BatchState:
        return batch(s.num_envs).advance(s, max_substeps)

    def ready(s: BatchState) -> jax.Array:
        return batch(s.num_envs).ready(s)

    def finish(s: BatchState, mask: jax.Array):
        s = batch(mask.shape[0]).finish(s, mask)
        return s, observe(s), s.info("episode_invalid")

    return EnvAdapter(reset=reset, step=step, success_tau=env_config.success_tau,
                      scheduler=SubstepScheduler(begin, advance, ready, finish, substep_chunk) if substep_chunk else None)

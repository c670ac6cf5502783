"""Correction counters of docs/task.md section 7 as a JAX pytree, updated at every 1 ms substep on
noise-free positions. The rule is `mjx_push.task_rules.correction_events` (shared with the CPU
environment's `mjx_push.export.corrections_np`): with d_k the object-goal distance at substep k, tau the success
radius and eps a dead band,
- overshoot: d_{k-1} < tau and d_k >= tau and |d_k - tau| > eps;
- distance: a flag is set when d_k > d_{k-1} + eps; while it is set, d_k < d_{k-1} - eps counts one
  correction and clears the flag.
d_{-1} = +inf at reset. Non-finite distances never count.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from mjx_push.task_rules import EPS, TAU, correction_events


@struct.dataclass
class Corrections:
    d_prev: jnp.ndarray  # distance at the previous substep (+inf after reset)
    flag: jnp.ndarray  # bool: the distance has grown since the last distance correction
    overshoot: jnp.ndarray  # int32 counter
    distance: jnp.ndarray  # int32 counter

    @classmethod
    def init(cls) -> "Corrections":
        return cls(
            d_prev=jnp.asarray(jnp.inf, jnp.result_type(float)),
            flag=jnp.asarray(False),
            overshoot=jnp.asarray(0, jnp.int32),
            distance=jnp.asarray(0, jnp.int32),
        )


def update(c: Corrections, d: jnp.ndarray, tau: float = TAU, eps: float = EPS) -> Corrections:
    """Counters after observing the distance `d` of one more substep."""
    over, counted, flag = correction_events(c.d_prev, c.flag, d, tau, eps, xp=jnp)
    return Corrections(
        d_prev=d,
        flag=flag,
        overshoot=c.overshoot + over.astype(jnp.int32),
        distance=c.distance + counted.astype(jnp.int32),
    )

"""The correction counters (docs/task.md section 7) on CPU: `mjx_push.task_rules.correction_events`, the
rule the MJX environment's `mjx_push.corrections` applies, on Python floats (float64), one substep at a
time. Kept apart from the JAX pytree for its layout: a frozen dataclass of Python scalars, cheap at every
1 ms substep and read directly by the evaluation's records.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mjx_push.task_rules import EPS, TAU, correction_events


@dataclass(frozen=True)
class Corrections:
    d_prev: float = math.inf
    flag: bool = False
    overshoot: int = 0
    distance: int = 0


def update(c: Corrections, d: float, tau: float = TAU, eps: float = EPS) -> Corrections:
    """Counters after observing the distance `d` of one more substep."""
    d = float(d)
    over, counted, flag = correction_events(c.d_prev, c.flag, d, tau, eps)
    return Corrections(d_prev=d, flag=bool(flag), overshoot=c.overshoot + int(over), distance=c.distance + int(counted))

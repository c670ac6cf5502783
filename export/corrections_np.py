"""NumPy port of `mjx_push.corrections` (docs/task.md section 7): the same counters, one substep at a time.

overshoot: d_{k-1} < tau and d_k >= tau and |d_k - tau| > eps; distance: a flag is set when
d_k > d_{k-1} + eps, and while it is set d_k < d_{k-1} - eps counts one correction and clears it.
d_{-1} = +inf at reset; non-finite distances never count (every comparison with NaN is False).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mjx_push.corrections import EPS, TAU


@dataclass(frozen=True)
class Corrections:
    d_prev: float = math.inf
    flag: bool = False
    overshoot: int = 0
    distance: int = 0


def update(c: Corrections, d: float, tau: float = TAU, eps: float = EPS) -> Corrections:
    """Counters after observing the distance `d` of one more substep."""
    d = float(d)
    over = c.d_prev < tau and d >= tau and abs(d - tau) > eps
    grew = d > c.d_prev + eps
    shrank = d < c.d_prev - eps
    counted = c.flag and shrank
    flag = False if counted else (c.flag or grew)
    return Corrections(d_prev=d, flag=flag, overshoot=c.overshoot + int(over), distance=c.distance + int(counted))

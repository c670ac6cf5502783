"""Progress of a training run: env steps, env steps/s, updates/s, success rate, mean reward, distance.

On a terminal: a rich progress bar. In a log (output not a terminal, e.g. redirected to a file or run
under a scheduler) a bar's redraws are unreadable and rich cuts its columns to 80 characters, so plain
lines are printed instead, whole: every evaluation, the first and last batch, and otherwise at most one
line per `log_every_s` seconds. `enabled=False` (`--no-progress`) prints only the evaluations.
"""

from __future__ import annotations

import time

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from mjx_push.train.config import LoopConfig


def _duration(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


class TrainProgress:
    def __init__(
        self, console: Console, loop: LoopConfig, episode_len: int, enabled: bool = True, log_every_s: float = 30.0
    ):
        self.loop = loop
        self.enabled = enabled
        self.console = console
        self.total = loop.num_iterations(episode_len) * loop.env_steps_per_iteration(episode_len)
        self.plain = not console.is_terminal  # a log file: whole lines, no bar
        self.log_every_s = log_every_s
        self.bar = Progress(
            TextColumn("[bold]env steps"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[rates]}"),
            TextColumn("{task.fields[scores]}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=console,
            disable=not enabled or self.plain,
        )
        self.task = None
        self.last_eval = ""
        self._t0 = time.monotonic()
        self._last_line = -float("inf")
        self._first: tuple[int, float] | None = None  # (env steps, time) after the first batch (compiled)

    def __enter__(self):
        self._t0 = time.monotonic()
        self.bar.__enter__()
        self.task = self.bar.add_task("train", total=self.total, rates="compiling...", scores="")
        return self

    def __exit__(self, *exc):
        return self.bar.__exit__(*exc)

    def _line(self, text: str) -> None:
        # soft_wrap: never cut or re-wrap a log line; no markup or highlighting in logs.
        self.console.print(text, soft_wrap=True, markup=False, highlight=False)

    def update(self, m: dict) -> None:
        steps = int(m["env_steps"])
        rates = f"{m['env_steps_per_s']:,.0f} steps/s  {m['updates_per_s']:,.0f} upd/s"
        scores = (
            f"train success {m['train/success_rate']:.0%} reward {m['train/mean_reward']:.1f} "
            f"final dist {100 * m['train/final_distance']:.1f} cm"
        )
        evaluated = "eval/mean_reward" in m
        if evaluated:
            self.last_eval = (
                f"  eval success {m['eval/success_rate']:.0%} reward {m['eval/mean_reward']:.1f} "
                f"final dist {100 * m['eval/final_distance']:.1f} cm"
            )
        self.bar.update(self.task, completed=steps, rates=rates, scores=scores + self.last_eval)
        now = time.monotonic()
        if not self.enabled:
            if evaluated:
                self._line(f"{steps:>9,} env steps: {scores}{self.last_eval}")
            return
        if not self.plain:
            return
        first = self._first is None
        if first:
            self._first = (steps, now)
        last = steps >= self.total
        if not (first or last or evaluated or now - self._last_line >= self.log_every_s):
            return
        self._last_line = now
        remaining = ""
        s0, t0 = self._first
        if steps > s0 and not last:  # rate since the first batch, which includes compilation
            remaining = f", ~{_duration((now - t0) / (steps - s0) * (self.total - steps))} left"
        self._line(
            f"{steps:>9,}/{self.total:,} env steps ({steps / self.total:.0%}) {rates}  {scores}"
            f"{self.last_eval}  [{_duration(now - self._t0)}{remaining}]"
        )

"""Rich progress bar of a training run: env steps, env steps/s, updates/s, success rate, mean reward."""

from __future__ import annotations

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from train.config import LoopConfig


class TrainProgress:
    def __init__(self, console: Console, loop: LoopConfig, enabled: bool = True):
        self.loop = loop
        self.enabled = enabled
        self.console = console
        self.bar = Progress(
            TextColumn("[bold]env steps"), BarColumn(), MofNCompleteColumn(),
            TextColumn("{task.fields[rates]}"), TextColumn("{task.fields[scores]}"),
            TimeElapsedColumn(), TimeRemainingColumn(), console=console, disable=not enabled,
        )
        self.task = None
        self.last_eval = ""

    def __enter__(self):
        self.bar.__enter__()
        self.task = self.bar.add_task("train", total=self.loop.num_iterations * self.loop.env_steps_per_iteration,
                                      rates="compiling...", scores="")
        return self

    def __exit__(self, *exc):
        return self.bar.__exit__(*exc)

    def update(self, m: dict) -> None:
        rates = f"{m['env_steps_per_s']:,.0f} steps/s  {m['updates_per_s']:,.0f} upd/s"
        scores = (f"train success {m['train/success_rate']:.0%} reward {m['train/mean_reward']:.1f} "
                  f"final dist {100 * m['train/final_distance']:.1f} cm")
        if "eval/mean_reward" in m:
            self.last_eval = (f"  eval success {m['eval/success_rate']:.0%} reward {m['eval/mean_reward']:.1f} "
                              f"final dist {100 * m['eval/final_distance']:.1f} cm")
            if not self.enabled:
                self.console.print(f"{int(m['env_steps']):>9,} env steps: {scores}{self.last_eval}")
        self.bar.update(self.task, completed=int(m["env_steps"]), rates=rates, scores=scores + self.last_eval)

"""`mjx-push demo`: the pushing scene stepped with random actions (`mjx_push.throughput.run`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path


@dataclasses.dataclass
class Demo:
    """Step a batch of pushing scenes with random actions; show substeps/s; write a PNG of the masks."""

    num_envs: int = 16
    """environments stepped in parallel (>= 2 for mixed shapes)"""
    steps: int = 20
    """environment steps (each runs 10-600 substeps of 1 ms)"""
    seed: int = 0
    out: Path = Path("outputs/demo")
    """folder for masks.png and demo.json"""
    shape: str = "any"
    """object shape filter: any, cylinder, cuboid, square, rectangular"""

    def run(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from mjx_push import objects, throughput
        from mjx_push.env import EnvConfig

        cfg = EnvConfig(objects=objects.ObjectConfig(shape=self.shape))
        console = Console()
        console.print(
            f"[bold]mjx-push demo[/]: {self.num_envs} environments, {self.steps} random steps "
            "(the first step includes JIT compilation)"
        )
        with Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TextColumn("{task.fields[sps]}"),
            TimeElapsedColumn(),
            console=console,
        ) as bar:
            task = bar.add_task("stepping", total=self.steps, sps="compiling...")

            def progress(i, total, sps):
                bar.update(task, completed=i, sps=f"{sps:,.0f} substeps/s" if sps else "compiling...")

            stats = throughput.run(cfg, self.num_envs, self.steps, self.seed, self.out, progress)
        for k, v in stats.items():
            console.print(f"  {k}: {v}")

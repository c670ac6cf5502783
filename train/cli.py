"""The `mjx-push` command line. Subcommands are generated from typed dataclasses with tyro."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Literal

import mjx_push  # noqa: F401  (applies the CPU XLA flag before jax starts)
import tyro


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

        from mjx_push import demo, objects
        from mjx_push.env import EnvConfig

        cfg = EnvConfig(objects=objects.ObjectConfig(shape=self.shape))
        console = Console()
        console.print(f"[bold]mjx-push demo[/]: {self.num_envs} environments, {self.steps} random steps "
                      "(the first step includes JIT compilation)")
        with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                      TextColumn("{task.fields[sps]}"), TimeElapsedColumn(), console=console) as bar:
            task = bar.add_task("stepping", total=self.steps, sps="compiling...")

            def progress(i, total, sps):
                bar.update(task, completed=i, sps=f"{sps:,.0f} substeps/s" if sps else "compiling...")

            stats = demo.run(cfg, self.num_envs, self.steps, self.seed, self.out, progress)
        for k, v in stats.items():
            console.print(f"  {k}: {v}")


@dataclasses.dataclass
class TrainEncoder:
    """Train the mask autoencoder (SPEC section 5) on masks drawn on device; report held-out IoU.

    The shipped encoder (mjx_push/assets/encoder.msgpack) was made by this command with
    `--out mjx_push/assets/encoder.msgpack`; its JSON record holds the exact command and seed."""

    steps: int = 6000
    batch_size: int = 64
    lr: float = 1e-3
    kl_weight: float = 1.0
    eval_masks: int = 1000
    eval_every: int = 500
    seed: int = 0
    out: Path = Path("outputs/encoder/encoder.msgpack")
    """encoder weights (msgpack); a JSON record with the same stem is written next to it"""

    def run(self) -> None:
        import platform
        import time

        import jax
        from rich.console import Console

        from mjx_push import encoder as enc
        from train.encoder import EncoderTrainConfig, train_encoder

        cfg = EncoderTrainConfig(steps=self.steps, batch_size=self.batch_size, lr=self.lr,
                                 kl_weight=self.kl_weight, eval_masks=self.eval_masks,
                                 eval_every=self.eval_every, seed=self.seed)
        console = Console()
        console.print(f"[bold]mjx-push train-encoder[/]: {cfg.steps} steps of {cfg.batch_size} fresh masks")

        def progress(step, row):
            console.print(f"  step {step:>6}  loss {row['loss']:8.2f}  held-out IoU {row['heldout_iou']:.4f}"
                          f"  {row['seconds']:7.0f} s")

        params, report = train_encoder(cfg, progress)
        record = {
            "command": (f"mjx-push train-encoder --steps {cfg.steps} --batch-size {cfg.batch_size} --lr {cfg.lr} "
                        f"--kl-weight {cfg.kl_weight} --eval-masks {cfg.eval_masks} --seed {cfg.seed} "
                        f"--out {self.out}"),
            "seed": cfg.seed,
            "created": time.strftime("%Y-%m-%d %H:%M:%S"),
            "jax": jax.__version__,
            "backend": jax.default_backend(),
            "machine": platform.processor() or platform.machine(),
            **report,
        }
        enc.save(self.out, params["encoder"], record)
        console.print(f"held-out IoU mean {report['iou_mean']:.4f} (5th percentile {report['iou_p05']:.4f}); "
                      f"encoder written to {self.out}")


@dataclasses.dataclass
class Train:
    """Train a pushing agent (SAC + HER) on the MJX scene: logs, checkpoints, best policy in --run-dir.

    Presets: smoke (a few minutes on 2 CPU cores, proves the pipeline), paper (the reference budget:
    29,000 env steps, 19,000 updates, batch 256), gpu (2,048 envs, sized for one H100). Any field left
    unset keeps the preset's value."""

    agent: Literal["vpm", "stacked", "ugru", "egru"] = "egru"
    preset: Literal["smoke", "paper", "gpu"] = "smoke"
    seed: int = 0
    run_dir: Path | None = None
    """default: runs/<agent>-<preset>-s<seed>"""
    resume: bool = False
    """continue the run in --run-dir from its latest checkpoint (same configuration required)"""
    encoder: Path | None = None
    """encoder weights (default: the shipped pretrained encoder)"""
    num_envs: int | None = None
    total_env_steps: int | None = None
    warmup_env_steps: int | None = None
    utd: float | None = None
    """gradient updates per environment step"""
    batch_size: int | None = None
    lr: float | None = None
    eval_every_env_steps: int | None = None
    eval_episodes: int | None = None
    checkpoint_every: int = 10
    """also checkpoint every this many episode batches (always at evaluations and at the end)"""
    progress: bool = True

    def config(self):
        from train import presets

        cfg = presets.make(self.agent, self.preset, self.seed)
        cfg = presets.override(cfg, **{
            "loop.num_envs": self.num_envs, "loop.total_env_steps": self.total_env_steps,
            "loop.warmup_env_steps": self.warmup_env_steps, "loop.utd": self.utd,
            "loop.eval_every_env_steps": self.eval_every_env_steps, "loop.eval_episodes": self.eval_episodes,
            "sac.batch_size": self.batch_size, "sac.lr": self.lr,
        })
        if self.encoder is not None:
            cfg = dataclasses.replace(cfg, encoder=str(self.encoder))
        return cfg

    def run(self) -> None:
        from rich.console import Console

        from train import run as run_mod
        from train.progress import TrainProgress

        console = Console()
        run_dir = self.run_dir or Path("runs") / f"{self.agent}-{self.preset}-s{self.seed}"
        if self.resume:
            cfg = run_mod.load_config(run_dir / "config.json")
            if self._overrides():
                raise ValueError("--resume continues the saved configuration; drop the other settings "
                                 f"({', '.join(self._overrides())})")
        else:
            cfg = self.config()
        loop = cfg.train.loop
        console.print(f"[bold]mjx-push train[/] {cfg.agent} ({self.preset}): {loop.num_envs} envs, "
                      f"{loop.total_env_steps:,} env steps, {loop.warmup_env_steps:,} warm-up, "
                      f"{loop.updates_per_iteration} updates per batch of {loop.env_steps_per_iteration} steps; "
                      f"run dir {run_dir}")
        console.print("  the first batch includes JIT compilation (minutes on CPU)")
        with TrainProgress(console, loop, enabled=self.progress) as bar:
            summary, _ = run_mod.run(cfg, run_dir, resume=self.resume, checkpoint_every=self.checkpoint_every,
                                     on_iteration=bar.update)
        console.print(f"best evaluation: mean reward {summary['best_eval_mean_reward']:.2f}, success "
                      f"{summary['best_eval_success_rate']:.0%} at {summary['best_env_steps']:,} env steps")
        console.print(f"policy: {run_dir / 'best_policy.msgpack'} (+ .json); logs: {run_dir / 'metrics.csv'}, "
                      f"TensorBoard {run_dir / 'tb'}; checkpoints: {run_dir / 'checkpoints'}")

    def _overrides(self) -> list[str]:
        names = ("num_envs", "total_env_steps", "warmup_env_steps", "utd", "batch_size", "lr",
                 "eval_every_env_steps", "eval_episodes", "encoder")
        return [n for n in names if getattr(self, n) is not None]


def main(argv: list[str] | None = None) -> int:
    commands = {"train": Train, "train-encoder": TrainEncoder, "demo": Demo}
    try:
        cmd = tyro.extras.subcommand_cli_from_dict(commands, args=argv, prog="mjx-push")
        cmd.run()
    except ValueError as e:  # configuration errors name the field: show them without a traceback
        print(f"mjx-push: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

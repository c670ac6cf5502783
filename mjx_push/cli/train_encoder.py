"""`mjx-push train-encoder`: the mask autoencoder (`mjx_push.train.encoder_training.train_encoder`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path


@dataclasses.dataclass
class TrainEncoder:
    """Train the mask autoencoder (docs/task.md section 5) on masks drawn on device; report held-out IoU.

    The shipped encoder (mjx_push/assets/encoder.msgpack) was made by this command with
    `--out mjx_push/assets/encoder.msgpack`; its JSON record holds the exact command and seed."""

    steps: int = 6000
    batch_size: int = 64
    lr: float = 1e-3
    kl_weight: float = 1.0
    yaw_weight: float = 0.0
    """weight of an auxiliary loss that makes the latent carry cuboid orientation (0: the paper's loss)"""
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
        from mjx_push.train.encoder_training import EncoderTrainConfig, train_encoder

        cfg = EncoderTrainConfig(
            steps=self.steps,
            batch_size=self.batch_size,
            lr=self.lr,
            kl_weight=self.kl_weight,
            yaw_weight=self.yaw_weight,
            eval_masks=self.eval_masks,
            eval_every=self.eval_every,
            seed=self.seed,
        )
        console = Console()
        console.print(f"[bold]mjx-push train-encoder[/]: {cfg.steps} steps of {cfg.batch_size} fresh masks")

        def progress(step, row):
            console.print(
                f"  step {step:>6}  loss {row['loss']:8.2f}  held-out IoU {row['heldout_iou']:.4f}"
                f"  {row['seconds']:7.0f} s"
            )

        params, report = train_encoder(cfg, progress)
        record = {
            "command": (
                f"mjx-push train-encoder --steps {cfg.steps} --batch-size {cfg.batch_size} --lr {cfg.lr} "
                f"--kl-weight {cfg.kl_weight} --yaw-weight {cfg.yaw_weight} --eval-masks {cfg.eval_masks} "
                f"--seed {cfg.seed} "
                f"--out {self.out}"
            ),
            "seed": cfg.seed,
            "created": time.strftime("%Y-%m-%d %H:%M:%S"),
            "jax": jax.__version__,
            "backend": jax.default_backend(),
            "machine": platform.processor() or platform.machine(),
            **report,
        }
        enc.save(self.out, params["encoder"], record)
        console.print(
            f"held-out IoU mean {report['iou_mean']:.4f} (5th percentile {report['iou_p05']:.4f}); "
            f"encoder written to {self.out}"
        )

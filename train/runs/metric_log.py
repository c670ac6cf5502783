"""A run's metric log: ``metrics.csv`` (one row per episode batch, rewritten atomically) and TensorBoard
scalars with environment steps on the x axis."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from mjx_push.train.runs import atomic


class MetricLog:
    """metrics.csv + TensorBoard. On resume, rows past the checkpoint are dropped (they will be redone)."""

    def __init__(self, root: Path, resume_env_steps: int | None, write: bool = True):
        from tensorboardX import SummaryWriter

        self.csv_path = root / "metrics.csv"
        self.rows: list[dict] = []
        if resume_env_steps is not None and self.csv_path.is_file():
            with self.csv_path.open() as f:
                self.rows = [r for r in csv.DictReader(f) if float(r["env_steps"]) <= resume_env_steps]
        self.columns: list[str] = list(self.rows[0].keys()) if self.rows else []
        # The other processes of a multi-process run keep their rows in memory only (process 0 writes).
        self.tb = SummaryWriter(str(root / "tb"), purge_step=resume_env_steps) if write else None

    def write(self, metrics: dict) -> None:
        new = [k for k in metrics if k not in self.columns]
        self.columns += new
        self.rows.append(metrics)
        if self.tb is None:
            return
        # Rewritten whole (columns may grow at evaluations), atomically: a kill mid-write keeps the old log.
        out = io.StringIO(newline="")
        w = csv.DictWriter(out, fieldnames=self.columns)
        w.writeheader()
        w.writerows(self.rows)
        atomic.write_text(self.csv_path, out.getvalue())
        step = int(metrics["env_steps"])
        for k, v in metrics.items():
            if k != "env_steps" and isinstance(v, (int, float)) and v == v:
                self.tb.add_scalar(k, v, step)
        self.tb.flush()

    def close(self):
        if self.tb is not None:
            self.tb.close()

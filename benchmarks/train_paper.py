"""Training at the `paper` preset: learning curves and throughput.

    python -m benchmarks.train_paper [--agents egru vpm] [--total-env-steps 29000] [--out outputs/bench_paper]

Trains each agent with `mjx-push train --preset paper` semantics in `OUT/<agent>` (resumable: rerun
the same command after an interruption and it continues), then prints and writes to
`OUT/bench_train_paper.json`: the learning curve (evaluation success rate and mean reward against
environment steps), the first batch's time (compilation + one batch), steady environment steps/s and
gradient steps/s (from batches without evaluation), evaluation time, and the best scores.
`--total-env-steps` shortens the run (and the curve) and `--eval-episodes` the evaluations when the
machine cannot afford the full budget.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import time
from pathlib import Path

import mjx_push  # noqa: F401  (CPU XLA flag)
import jax
import numpy as np
from rich.console import Console
from rich.table import Table

from train import presets
from train import run as run_mod


def curve_and_rates(run_dir: Path, cfg: presets.RunConfig) -> dict:
    with (run_dir / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    loop = cfg.train.loop
    evals = [r for r in rows if r.get("eval/mean_reward")]
    plain = [r for r in rows[1:] if not r.get("eval/mean_reward")]
    learning = [r for r in plain if r["learning"] in ("True", "1", "1.0")]
    warm = [r for r in plain if r not in learning]
    t = lambda rs: float(np.mean([float(r["iteration_s"]) for r in rs])) if rs else None  # noqa: E731
    t_learn, t_warm = t(learning), t(warm)
    t_eval = (float(np.mean([float(r["iteration_s"]) for r in evals[:-1]])) - (t_learn or 0)) if len(evals) > 1 else None
    return {
        "curve": [{"env_steps": int(float(r["env_steps"])), "success_rate": float(r["eval/success_rate"]),
                   "mean_reward": float(r["eval/mean_reward"])} for r in evals],
        "first_batch_s": float(rows[0]["iteration_s"]),
        "env_steps_per_s_warmup": loop.env_steps_per_iteration / t_warm if t_warm else None,
        "env_steps_per_s_learning": loop.env_steps_per_iteration / t_learn if t_learn else None,
        # Gradient steps/s net of the rollout: the learning batches' extra time over warm-up batches.
        "grad_steps_per_s": (loop.updates_per_iteration / (t_learn - t_warm)) if (t_learn and t_warm and t_learn > t_warm) else None,
        "eval_s": t_eval,
        "wall_s": float(rows[-1]["wall_s"]),
        "batches": len(rows),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", nargs="+", default=["egru", "vpm"])
    ap.add_argument("--total-env-steps", type=int, default=None)
    ap.add_argument("--eval-episodes", type=int, default=None, help="fewer evaluation episodes than the preset's 100")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_paper"))
    args = ap.parse_args()
    console = Console(width=max(Console().width, 150))  # the table has nine columns
    results = {}
    for agent in args.agents:
        cfg = presets.make(agent, "paper", args.seed)
        cfg = presets.override(cfg, **{"loop.total_env_steps": args.total_env_steps,
                                        "loop.eval_episodes": args.eval_episodes})
        run_dir = args.out / agent
        resume = (run_dir / "checkpoints").is_dir() and any((run_dir / "checkpoints").iterdir())
        if not (run_dir / "summary.json").is_file():
            console.print(f"{'resuming' if resume else 'training'} {agent} in {run_dir}")
            t0 = time.perf_counter()
            run_mod.run(cfg, run_dir, resume=resume,
                        on_iteration=lambda m: console.print(
                            f"  {agent} {int(m['env_steps']):>6} steps  {m['iteration_s']:6.1f} s/batch"
                            + (f"  eval success {m['eval/success_rate']:.2f} reward {m['eval/mean_reward']:.1f}"
                               if "eval/mean_reward" in m else "")))
            console.print(f"  {agent}: {time.perf_counter() - t0:.0f} s")
        summary = json.loads((run_dir / "summary.json").read_text())
        results[agent] = {**curve_and_rates(run_dir, cfg), "best": {k: summary[k] for k in summary if k.startswith("best")},
                          "config": {"num_envs": cfg.train.loop.num_envs, "total_env_steps": cfg.train.loop.total_env_steps,
                                     "updates_per_batch": cfg.train.loop.updates_per_iteration,
                                     "batch_size": cfg.train.sac.batch_size}}

    table = Table(title="paper preset: learning curves and throughput")
    for col in ("agent", "env steps", "eval success", "eval reward", "first batch s", "env steps/s (warm-up)",
                "env steps/s (learning)", "grad steps/s", "wall min"):
        table.add_column(col, justify="right")
    for agent, r in results.items():
        fmt = lambda v, f="{:,.1f}": "-" if v is None else f.format(v)  # noqa: E731
        for i, point in enumerate(r["curve"]):
            first = i == 0
            table.add_row(agent if first else "", f"{point['env_steps']:,}", f"{point['success_rate']:.2f}",
                          f"{point['mean_reward']:.1f}",
                          fmt(r["first_batch_s"]) if first else "", fmt(r["env_steps_per_s_warmup"]) if first else "",
                          fmt(r["env_steps_per_s_learning"]) if first else "", fmt(r["grad_steps_per_s"]) if first else "",
                          fmt(r["wall_s"] / 60) if first else "")
    console.print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    record = {"machine": f"{platform.machine()}, {__import__('os').cpu_count()} CPU cores, jax {jax.__version__} "
                         f"backend {jax.default_backend()}", "results": results}
    (args.out / "bench_train_paper.json").write_text(json.dumps(record, indent=2) + "\n")
    console.print(f"written {args.out / 'bench_train_paper.json'}")


if __name__ == "__main__":
    main()

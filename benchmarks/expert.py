"""The scripted expert (mjx_push.expert) on the evaluation protocol: how well the task can be done
with a given action box, and what it costs to simulate.

    python -m benchmarks.expert [--presets cpu reference] [--episodes 128] [--out outputs/bench_expert.json]
                                [--settle 0.9 0.8] [--cases standard] [--seed 3000017]

For each preset's action box (``cpu``: the measured presets' box; ``reference``: the paper's) it runs
the expert on the standard setting (all shapes) and on the paper's difficult case per shape, with the
evaluation seeds every agent meets, and prints success within 1 cm (and 2 and 5 cm), the median and
worst final object-goal distance, the mean substeps per environment step (simulation cost) and the
wall time (compilation included). `--settle` runs the expert at other step lengths (the fraction of
its offset a step should reach: shorter steps, less physics per env step); `--cases standard` keeps
the standard setting only; `--seed` draws the episodes from another seed (a selection seed when the
figures are to choose a setting: the default is the test episodes' seed).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from benchmarks.output import write_json
from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import numpy as np
from rich.console import Console
from rich.table import Table

from mjx_push.train import presets
from mjx_push.train.evaluate import ExpertPolicy, evaluate
from mjx_push.train.episodes import EvalSpec

CASES = (("standard", "all"), ("difficult", "cylinder"), ("difficult", "square"), ("difficult", "rectangular"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--presets", nargs="+", default=["cpu"], choices=presets.PRESETS)
    ap.add_argument("--episodes", type=int, default=128)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_expert.json"))
    ap.add_argument("--settle", type=float, nargs="+", default=None, help="step lengths (default: the preset's)")
    ap.add_argument("--cases", choices=["all", "standard"], default="all")
    ap.add_argument("--seed", type=int, default=EvalSpec.seed, help="the episodes' seed")
    args = ap.parse_args(argv)
    if args.settle is not None and not all(0 < x < 1 for x in args.settle):
        ap.error(f"--settle values must lie in (0, 1), got {args.settle}")
    console = Console(width=150)
    rows = []
    cases = CASES if args.cases == "all" else CASES[:1]
    for preset in args.presets:
        run = presets.make("vpm", preset)
        for settle in args.settle or [run.expert.settle]:
            policy = ExpertPolicy(dataclasses.replace(run, expert=dataclasses.replace(run.expert, settle=settle)))
            env = policy.config.env
            for setting, shape in cases:
                t0 = time.perf_counter()
                res = evaluate(
                    policy,
                    EvalSpec(
                        setting=setting,
                        shape=shape,
                        episodes=args.episodes,
                        seed=args.seed,
                        batch=min(args.batch, args.episodes),
                    ),
                )
                per = res["per_episode"]
                ok = ~per["invalid"].astype(bool)
                final = per["final_distance"]
                rows.append(
                    {
                        "preset": preset,
                        "action_scale": env.action_scale,
                        "gain": env.controller.gain,
                        "substeps": list(env.substeps),
                        "settle": settle,
                        "seed": args.seed,
                        "setting": setting,
                        "shape": shape,
                        "episodes": args.episodes,
                        **{f"success_{c}cm": float(np.mean(ok & (final < c / 100))) for c in (1, 2, 5)},
                        "median_final_mm": float(np.median(final) * 1000),
                        "worst_final_mm": float(np.max(final) * 1000),
                        "overshoot": float(np.mean(per["overshoot"])),
                        "distance": float(np.mean(per["distance"])),
                        "mean_substeps_per_step": float(np.mean(per["mean_substeps"])),
                        "invalid": int(np.sum(~ok)),
                        "wall_s": time.perf_counter() - t0,
                    }
                )
                console.print(rows[-1])
    table = Table(title=f"scripted expert, {args.episodes} episodes per case (seed {args.seed})")
    for col in (
        "preset (box)",
        "setting",
        "shape",
        "1 cm",
        "2 cm",
        "5 cm",
        "median / worst final",
        "corrections o/d",
        "substeps/step",
        "wall",
    ):
        table.add_column(col, justify="right")
    for r in rows:
        box = (
            f"{r['preset']} (+-{r['action_scale']} m, gain {r['gain']:g}, {r['substeps'][0]}-{r['substeps'][1]},"
            f" settle {r['settle']:g})"
        )
        table.add_row(
            box,
            r["setting"],
            r["shape"],
            f"{r['success_1cm']:.0%}",
            f"{r['success_2cm']:.0%}",
            f"{r['success_5cm']:.0%}",
            f"{r['median_final_mm']:.1f} / {r['worst_final_mm']:.1f} mm",
            f"{r['overshoot']:.2f} / {r['distance']:.2f}",
            f"{r['mean_substeps_per_step']:.0f}",
            f"{r['wall_s']:.0f} s",
        )
    console.print(table)
    write_json(args.out, {"rows": rows})


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()

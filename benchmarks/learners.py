"""What SAC+HER adds to cloning: three learners on one budget, each a config field, side by side.

    python -m benchmarks.learners [--rung egru-1cm] [--seeds 1 2] [--total-env-steps 28800]
        [--anneal 9600 22400] [--anchor-weight 2] [--episodes 100] [--out outputs/learners]

The learners (every other setting is the rung's preset):

- ``bc``: cloning alone (``train.sac.actor_loss=bc``): the actor minimises the cloning term on the
  expert's labels of every stored step and never reads the critics (DAgger with the scripted expert);
- ``sacbc``: SAC+HER with the cloning term (the presets' learner);
- ``anneal``: SAC+HER with the teacher annealed away (``train.demo.anneal_start/anneal_end``): the
  cloning weight and the expert's share of environments fall linearly to 0, and the last stretch of
  training is the agent's own;
- ``anchor``: as ``anneal``, and the actor held to its own copy of ``anneal_start`` as the teacher
  goes (``train.sac.anchor_weight``): the cloning term's weight passes to the distance from that copy,
  so what was cloned is kept while the critic, not the expert, moves the actor.

Each run trains through `benchmarks.learning_ladder` (in ``OUT/<rung>-<learner>-s<seed>/``, resumable:
rerunning continues interrupted runs and reuses finished ones). Then its best actor (selected on the
in-run evaluation's episodes) and its final actor are scored on ``--episodes`` episodes of the
protocol's standard setting and of its difficult case, from the protocol's test seed (never the
selection's episodes): success within 1, 2 and 5 cm, overshoot and distance corrections, final
distance. Evaluations are cached beside each run. Printed: per learner, the mean over seeds and each
seed's value; written: ``OUT/learners.json``.

Wall times are of this machine with whatever else runs on it: say so when you quote them.
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
import numpy as np
from rich.console import Console
from rich.table import Table

from benchmarks import learning_ladder as ladder
from mjx_push.train.runs import atomic

LEARNERS = ("bc", "sacbc", "anneal", "anchor")


def learner_overrides(learner: str, anneal: tuple[int, int], anchor_weight: float = 2.0) -> list[str]:
    annealed = [f"train.demo.anneal_start={anneal[0]}", f"train.demo.anneal_end={anneal[1]}"]
    return {
        "bc": ['train.sac.actor_loss="bc"'],
        "sacbc": [],
        "anneal": annealed,
        "anchor": [*annealed, f"train.sac.anchor_weight={anchor_weight}"],
    }[learner]


def score(run_dir: Path, which: str, setting: str, episodes: int) -> dict:
    """One actor of a finished run on the protocol's test episodes, cached as JSON in the run dir."""
    cache = run_dir / f"score-{which}-{setting}-{episodes}.json"
    weights = (run_dir / which).with_suffix(".msgpack")
    stamp = weights.stat().st_mtime_ns
    if cache.is_file():
        cached = json.loads(cache.read_text())
        if cached.get("weights_mtime_ns") == stamp:
            return cached["score"]
    out = ladder.score(run_dir, which, episodes, setting)
    atomic.write_text(cache, json.dumps({"weights_mtime_ns": stamp, "score": out}) + "\n")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rung", default="egru-1cm", choices=sorted(ladder.RUNGS))
    ap.add_argument("--learners", nargs="+", default=list(LEARNERS), choices=LEARNERS)
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--total-env-steps", type=int, default=28_800)
    ap.add_argument(
        "--anneal",
        nargs=2,
        type=int,
        default=[9_600, 22_400],
        metavar=("START", "END"),
        help="env steps over which the annealed learner's teacher falls to 0",
    )
    ap.add_argument("--anchor-weight", type=float, default=2.0, help="the anchored learner's train.sac.anchor_weight")
    ap.add_argument("--episodes", type=int, default=100, help="test episodes per actor and setting")
    ap.add_argument("--no-train", action="store_true", help="score the finished runs only")
    ap.add_argument("--out", type=Path, default=Path("outputs/learners"))
    args = ap.parse_args(argv)

    console = Console(width=170)
    rows = []
    for learner in args.learners:
        for seed in args.seeds:
            run_dir = args.out / f"{args.rung}-{learner}-s{seed}"
            if not args.no_train:
                ladder.main(
                    [
                        "--rungs",
                        args.rung,
                        "--seeds",
                        str(seed),
                        "--total-env-steps",
                        str(args.total_env_steps),
                        "--eval-episodes",
                        "0",
                        "--out",
                        str(args.out),
                        "--tag",
                        learner,
                    ]
                    + (
                        ["--set", *overrides]
                        if (overrides := learner_overrides(learner, args.anneal, args.anchor_weight))
                        else []
                    )
                )
            if not (run_dir / "summary.json").is_file():
                console.print(f"[yellow]{run_dir} has not finished: skipped")
                continue
            summary = json.loads((run_dir / "summary.json").read_text())
            row = {
                "learner": learner,
                "seed": seed,
                "run_dir": str(run_dir),
                "env_steps": summary["env_steps"],
                "train_wall_s": summary["wall_s"],
                "best_env_steps": summary["best_env_steps"],
            }
            for which in ("best_policy", "final_policy"):
                for setting in ("standard", "difficult"):
                    row[f"{which}/{setting}"] = score(run_dir, which, setting, args.episodes)
            rows.append(row)

    table = Table(
        title=f"learners on {args.rung}, {args.total_env_steps:,} env steps, {args.episodes} test "
        "episodes per actor and setting (mean over seeds; per seed in brackets)"
    )
    for col in (
        "learner",
        "actor",
        "setting",
        "1 cm %",
        "1 cm cuboids",
        "1 cm cylinders",
        "5 cm %",
        "overshoot corr.",
        "distance corr.",
        "final distance (cm)",
    ):
        table.add_column(col, justify="right")
    for learner in args.learners:
        mine = [r for r in rows if r["learner"] == learner]
        if not mine:
            continue
        for which in ("best_policy", "final_policy"):
            for setting in ("standard", "difficult"):
                vals = [r[f"{which}/{setting}"] for r in mine]

                def cell(key, scale=100.0, digits=0):
                    v = [x[key] for x in vals]
                    f = lambda a: f"{scale * a:.{digits}f}"  # noqa: E731
                    return f"{f(np.mean(v))} ({', '.join(f(a) for a in v)})"

                table.add_row(
                    learner,
                    which.split("_")[0],
                    setting,
                    cell("success_1cm"),
                    cell("success_1cm_cuboid"),
                    cell("success_1cm_cylinder"),
                    cell("success_5cm"),
                    cell("overshoot", 1.0, 2),
                    cell("distance", 1.0, 2),
                    cell("final_distance", 100.0, 1),
                )
    console.print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    out = args.out / "learners.json"
    out.write_text(
        json.dumps(
            {
                "machine": platform.processor() or platform.machine(),
                "backend": jax.default_backend(),
                "rung": args.rung,
                "total_env_steps": args.total_env_steps,
                "anneal": args.anneal,
                "anchor_weight": args.anchor_weight,
                "episodes": args.episodes,
                "runs": rows,
            },
            indent=2,
        )
        + "\n"
    )
    console.print(f"written {out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()

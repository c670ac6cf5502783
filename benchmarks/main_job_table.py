"""The main job's scored runs, printed from their committed evaluation files as a markdown table.

    python -m benchmarks.main_job_table [docs/data/main-job]

Reads every `vpm-cpu[-STEPS]-s<SEED>-<COMMIT>[-seed<E>].json` there (`mjx-push eval RUN --setting
standard --episodes 100 --seed E --out FILE` of a run trained to STEPS env steps, the preset's 35,200
when the name gives none, at COMMIT with training seed SEED) and prints one row per budget, commit
and evaluation seed: success within 1 cm per training seed, its mean over seeds with a 95 % bootstrap
interval over seeds (the training seed is the unit: `mjx_push.train.comparison.seed_stats`), cuboids
(the even episodes) and cylinders (the odd ones), and within 5 cm.
"""

from __future__ import annotations

import json
import re
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from mjx_push.train.comparison import seed_stats

NAME = re.compile(r"vpm-cpu(?:-(?P<steps>\d+))?-s(?P<seed>\d+)-(?P<commit>[0-9a-f]{7,40})(?:-seed\d+)?\.json")
PRESET_STEPS = 35_200


def scores(record: dict) -> dict:
    """Per-shape and overall success of one evaluation file, in %."""
    ep = record["per_episode"]
    success = np.asarray(ep["success"], bool)
    final = np.asarray(ep["final_distance"], float)
    invalid = np.asarray(ep.get("invalid", np.zeros_like(success)), bool)
    return {
        "1cm": 100 * success.mean(),
        "cuboids": 100 * success[0::2].mean(),
        "cylinders": 100 * success[1::2].mean(),
        "5cm": 100 * ((final < 0.05) & ~invalid).mean(),
    }


def collect(folder: Path) -> dict:
    """{(steps, commit, eval seed): {training seed: scores}} for the files of `folder`."""
    rows: dict = defaultdict(dict)
    for path in sorted(folder.glob("vpm-cpu*.json")):
        m = NAME.fullmatch(path.name)
        if m is None:
            continue
        record = json.loads(path.read_text())
        steps = int(m["steps"] or PRESET_STEPS)
        rows[steps, m["commit"], int(record["spec"]["seed"])][int(m["seed"])] = scores(record)
    return rows


def table(rows: dict) -> str:
    lines = [
        "| env steps | trained at | evaluation seed | within 1 cm, seeds | mean (95 % interval over seeds) "
        "| cuboids | cylinders | within 5 cm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (steps, commit, eval_seed), by_seed in sorted(rows.items()):
        seeds = sorted(by_seed)
        col = lambda k: " / ".join(f"{by_seed[s][k]:.0f}" for s in seeds)  # noqa: E731
        mean, low, high = seed_stats.per_task_mean(np.asarray([[by_seed[s]["1cm"]] for s in seeds]))
        lines.append(
            f"| {steps:,} | {commit} | {eval_seed:,} | {col('1cm')} % (seeds {', '.join(map(str, seeds))}) "
            f"| {mean[0]:.1f} % ({low[0]:.0f}-{high[0]:.0f}) | {col('cuboids')} % | {col('cylinders')} % "
            f"| {col('5cm')} % |"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    folder = Path(argv[0]) if argv else Path("docs/data/main-job")
    rows = collect(folder)
    if not rows:
        raise SystemExit(f"no evaluation files named vpm-cpu[-STEPS]-s<SEED>-<COMMIT>[-seed<E>].json in {folder}")
    print(table(rows))


if __name__ == "__main__":
    main()

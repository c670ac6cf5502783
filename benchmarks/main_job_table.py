"""The main job's scored runs, printed from their committed evaluation files as a markdown table.

    python -m benchmarks.main_job_table [docs/data/main-job]

Reads every `vpm-cpu[-STEPS]-s<SEED>-<COMMIT>[-seed<E>].json` there (`mjx-push eval RUN --setting
standard --episodes 100 --seed E --out FILE` of a run trained to STEPS env steps, the preset's 35,200
when the name gives none, at COMMIT with training seed SEED) and prints one row per budget, commit
and evaluation seed: success within 1 cm per training seed, its mean over seeds and their range (the
training seed is the unit; with three seeds a bootstrap interval is that range), cuboids (the even
episodes) and cylinders (the odd ones), and within 5 cm. Only the standard setting over both shapes
is read: a file of another setting or shape, two files of one row and seed, or a file that is not an
evaluation is refused, naming it.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np

NAME = re.compile(r"vpm-cpu(?:-(?P<steps>\d+))?-s(?P<seed>\d+)-(?P<commit>[0-9a-f]{7,40})(?:-seed\d+)?\.json")
PRESET_STEPS = 35_200


def scores(record: dict) -> dict:
    """Per-shape and overall success of one evaluation record, in %."""
    ep = record["per_episode"]
    success = np.asarray(ep["success"], bool)
    final = np.asarray(ep["final_distance"], float)
    invalid = np.asarray(ep["invalid"], bool)
    return {
        "1cm": 100 * success.mean(),
        "cuboids": 100 * success[0::2].mean(),
        "cylinders": 100 * success[1::2].mean(),
        "5cm": 100 * ((final < 0.05) & ~invalid).mean(),
    }


def collect(folder: Path) -> dict:
    """{(steps, commit, eval seed): {training seed: scores}} for the evaluation files of `folder`."""
    rows: dict = {}
    for path in sorted(folder.glob("vpm-cpu*.json")):
        m = NAME.fullmatch(path.name)
        if m is None:
            continue
        try:
            record = json.loads(path.read_text())
            spec = record["spec"]
            if (spec["setting"], spec["shape"]) != ("standard", "all"):
                raise SystemExit(f"{path}: the table reads the standard setting over both shapes, got {spec}")
            row = rows.setdefault((int(m["steps"] or PRESET_STEPS), m["commit"], int(spec["seed"])), {})
            seed = int(m["seed"])
            if seed in row:
                raise SystemExit(f"{path}: a second evaluation of training seed {seed} for the same row")
            row[seed] = scores(record)
        except (KeyError, TypeError, ValueError) as e:
            raise SystemExit(f"{path}: not an evaluation record of `mjx-push eval --out` ({e!r})") from e
    return rows


def table(rows: dict) -> str:
    lines = [
        "| env steps | trained at | evaluation seed | within 1 cm, seeds | mean (range over seeds) "
        "| cuboids | cylinders | within 5 cm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (steps, commit, eval_seed), by_seed in sorted(rows.items()):
        seeds = sorted(by_seed)
        col = lambda k: " / ".join(f"{by_seed[s][k]:.0f}" for s in seeds)  # noqa: E731
        one_cm = [by_seed[s]["1cm"] for s in seeds]
        lines.append(
            f"| {steps:,} | {commit} | {eval_seed:,} | {col('1cm')} % (seeds {', '.join(map(str, seeds))}) "
            f"| {np.mean(one_cm):.1f} % ({min(one_cm):.0f}-{max(one_cm):.0f}) | {col('cuboids')} % "
            f"| {col('cylinders')} % | {col('5cm')} % |"
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

"""The selection of a protocol's open settings, printed from its committed data as a markdown table.

    python -m benchmarks.selection_table docs/data/selection-v1.json

Per variant: success within 1 cm per shape and its mean over shapes on the selection episodes (the
decision's score), the overshoot corrections, and the in-run success curve on the standard setting.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

SHAPES = ("cylinder", "square", "rectangular")


def table(data: dict) -> str:
    lines = [
        "| variant | cylinder | square cuboid | rectangular cuboid | mean | overshoot corr. (cyl / sq / rect) "
        "| in-run success, standard setting (each evaluation) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, variant in data["variants"].items():
        success = [100 * variant["selection"][s]["success"]["mean"] for s in SHAPES]
        overshoot = " / ".join(f"{variant['selection'][s]['overshoot']['mean']:.2f}" for s in SHAPES)
        curve = " / ".join(f"{100 * v:.0f}" for _, v in variant["in_run_standard_success"])
        cells = " | ".join(f"{v:.0f} %" for v in success)
        lines.append(f"| {name} | {cells} | {sum(success) / len(SHAPES):.1f} % | {overshoot} | {curve} % |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m benchmarks.selection_table SELECTION.json", file=sys.stderr)
        return 2
    print(table(json.loads(Path(args[0]).read_text())))
    return 0


if __name__ == "__main__":
    sys.exit(main())

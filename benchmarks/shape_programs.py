"""What one MJX substep program for both object shapes would cost and save, against the two programs
(one per shape) that `mjx_push.batch.PushBatch` compiles now.

    python -m benchmarks.shape_programs [--envs-per-core 16] [--substeps 100] [--repeats 2]
                                        [--out outputs/bench_shape_programs.json]

"one per shape": the scene's box model and its cylinder model, each a jitted scan of `--substeps`
vmapped `mjx.step`s over half of `--envs-per-core` environments (the batch gives each shape half of
every device's environments). "both shapes": one model whose object body holds a box and a cylinder
geom, the unused one parked 1 m above the table (its collisions still computed, as they would be for
any environment of a merged batch), over all `--envs-per-core`. Per variant: the StableHLO's lines,
trace and lowering, XLA compilation, and the best of three runs per substep, on one device (one
core's share of a batch). Variants alternate `--repeats` times, so a busy machine slows both alike.
Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from mjx_push import xla  # noqa: F401  (the CPU fusion-emitter flag, before jax)
import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
from rich.console import Console
from rich.table import Table

from benchmarks.output import write_json
from mjx_push import scene

_PARKED_CYLINDER = (
    '<geom name="object_cylinder" type="cylinder" size="0.045 0.03" pos="0 0 1" mass="0" '
    'friction="0.5 0.005 0.0001" contype="2" conaffinity="1"/>'
)


def model(shape: str) -> mujoco.MjModel:
    """The scene's model for "box" or "cylinder"; "both": the box scene with a parked cylinder added."""
    if shape != "both":
        return scene.build_model(shape)
    xml = scene.build_xml("box")
    anchor = 'material="object"/>'
    if xml.count(anchor) != 1:
        raise RuntimeError("the scene's object geom changed: update benchmarks/shape_programs.py")
    return mujoco.MjModel.from_xml_string(xml.replace(anchor, anchor + _PARKED_CYLINDER))


def measure(shape: str, envs: int, substeps: int) -> dict:
    m = model(shape)
    mx = mjx.put_model(m)
    d = mjx.make_data(mx).replace(qpos=jnp.asarray(m.qpos0))
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (envs,) + x.shape), d)

    def run(ds):
        step = jax.vmap(lambda one: mjx.step(mx, one))
        return jax.lax.scan(lambda ds, _: (step(ds), None), ds, None, length=substeps)[0]

    t = time.perf_counter()
    lowered = jax.jit(run).lower(batch)
    lower_s = time.perf_counter() - t
    t = time.perf_counter()
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t
    jax.block_until_ready(compiled(batch))
    runs = []
    for _ in range(3):
        t = time.perf_counter()
        jax.block_until_ready(compiled(batch))
        runs.append(time.perf_counter() - t)
    return {
        "shape": shape,
        "envs": envs,
        "contacts": int(d._impl.ncon),
        "constraint_rows": int(d._impl.efc_J.shape[0]),
        "stablehlo_lines": lowered.as_text().count("\n"),
        "lower_s": lower_s,
        "compile_s": compile_s,
        "substep_ms": min(runs) / substeps * 1e3,
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--envs-per-core", type=int, default=16)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_shape_programs.json"))
    args = ap.parse_args(argv)
    if args.envs_per_core < 2 or args.envs_per_core % 2:
        ap.error(f"--envs-per-core must be an even number >= 2, got {args.envs_per_core}")
    half = args.envs_per_core // 2
    rounds = []
    for _ in range(args.repeats):
        box, cyl = measure("box", half, args.substeps), measure("cylinder", half, args.substeps)
        both = measure("both", args.envs_per_core, args.substeps)
        rounds.append(
            {
                "rows": [box, cyl, both],
                "one_per_shape": {
                    "compile_s": box["compile_s"] + cyl["compile_s"],
                    "lower_s": box["lower_s"] + cyl["lower_s"],
                    "substep_ms": box["substep_ms"] + cyl["substep_ms"],
                },
                "both_shapes": {k: both[k] for k in ("compile_s", "lower_s", "substep_ms")},
            }
        )
    table = Table(title=f"MJX substep programs, {args.envs_per_core} environments on one device")
    for col in ("round", "programs", "contacts / rows", "HLO lines", "lower s", "compile s", "substep ms"):
        table.add_column(col, justify="right" if col != "programs" else "left")
    for i, r in enumerate(rounds):
        box, cyl, both = r["rows"]
        one = r["one_per_shape"]
        table.add_row(
            str(i),
            f"one per shape ({half} + {half} envs)",
            f"{box['contacts']}/{box['constraint_rows']}, {cyl['contacts']}/{cyl['constraint_rows']}",
            f"{box['stablehlo_lines']} + {cyl['stablehlo_lines']}",
            f"{one['lower_s']:.1f}",
            f"{one['compile_s']:.1f}",
            f"{one['substep_ms']:.2f}",
        )
        table.add_row(
            str(i),
            f"both shapes ({args.envs_per_core} envs)",
            f"{both['contacts']}/{both['constraint_rows']}",
            str(both["stablehlo_lines"]),
            f"{both['lower_s']:.1f}",
            f"{both['compile_s']:.1f}",
            f"{both['substep_ms']:.2f}",
        )
    Console(width=120).print(table)
    write_json(args.out, {"options": vars(args) | {"out": str(args.out)}, "rounds": rounds})


if __name__ == "__main__":
    main()

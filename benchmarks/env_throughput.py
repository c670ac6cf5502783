"""Environment throughput: compile time, substeps/s, env steps/s and utilisation per batch size and a_s.

    python -m benchmarks.env_throughput [--batch-sizes 2 8 32 128] [--steps 5] [--out outputs/bench_env.json]

For each batch size it compiles the mixed-shape batch once, then times `--steps` environment steps at
a_s decoding to 10, 300 and 600 substeps and at random a_s. "executed" counts the substeps the batch
actually ran (every environment of a shape group waits for the group's largest a_s), "useful" those the
environments asked for; utilisation = useful / executed.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
import jax.numpy as jnp
from rich.console import Console
from rich.table import Table

from mjx_push.batch import PushBatch
from mjx_push.env import EnvConfig


def a_s_value(n: int, lo=10, hi=600) -> float:
    return 2.0 * (n + 0.5 - lo) / (hi - lo) - 1.0


def measure(num_envs: int, steps: int, seed: int = 0) -> list[dict]:
    batch = PushBatch(EnvConfig(), num_envs)
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    state = jax.block_until_ready(batch.jit_reset(key))
    reset_compile = time.perf_counter() - t0
    zero = jnp.zeros((num_envs, 3)).at[:, 2].set(-1.0)
    t0 = time.perf_counter()
    state = jax.block_until_ready(batch.jit_step(state, zero))
    step_compile = time.perf_counter() - t0
    rows = []
    for mode in ("10", "300", "600", "random"):
        useful = executed = 0
        t0 = time.perf_counter()
        for i in range(steps):
            k = jax.random.fold_in(key, i)
            a = jax.random.uniform(k, (num_envs, 3), minval=-0.05, maxval=0.05)  # small moves
            if mode == "random":
                a = a.at[:, 2].set(jax.random.uniform(jax.random.fold_in(k, 1), (num_envs,), minval=-1, maxval=1))
            else:
                a = a.at[:, 2].set(a_s_value(int(mode)))
            state = jax.block_until_ready(batch.jit_step(state, a))
            n = state.info["substeps"]
            useful += int(jnp.sum(n))
            executed += int(sum(int(jnp.max(p)) * p.shape[0] for p in batch._split(n)))
        dt = time.perf_counter() - t0
        rows.append(
            dict(
                num_envs=num_envs,
                a_s=mode,
                reset_compile_s=round(reset_compile, 2),
                step_compile_s=round(step_compile, 2),
                env_steps_per_s=round(steps * num_envs / dt, 2),
                useful_substeps_per_s=round(useful / dt, 1),
                executed_substeps_per_s=round(executed / dt, 1),
                utilisation=round(useful / executed, 4),
                invalid=int(jnp.sum(state.info["invalid_count"])),
            )
        )
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batch-sizes", type=int, nargs="+", default=[2, 8, 32, 128])
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--out", type=Path, default=Path("outputs/bench_env.json"))
    args = p.parse_args(argv)
    console = Console(width=160)
    rows = []
    for n in args.batch_sizes:
        console.print(f"batch {n} ...")
        rows += measure(n, args.steps)
    table = Table(title=f"mjx-push environment throughput ({jax.devices()[0].device_kind}, {jax.default_backend()})")
    for col in rows[0]:
        table.add_column(col)
    for r in rows:
        table.add_row(*[str(v) for v in r.values()])
    console.print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"device": str(jax.devices()[0]), "rows": rows}, indent=2))
    console.print(f"wrote {args.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()

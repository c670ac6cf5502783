"""A one-device run's training rollout on several host devices: split by whole episodes (the default:
each device runs its share of the batch as a batch of its own, `mjx_push.train.rollout.make_split_collect`)
against split by physics only (the adapter's batch over the devices, joined every tick; what runs
when the adapter offers no one-device twin, and what ran before).

    python -m benchmarks.rollout_split [--agent egru] [--preset cpu-long] [--pairs 3] [--out OUT.json]

Both rollouts are compiled in one process from the preset's run configuration (the same episodes), then
timed in `--pairs` interleaved pairs (the order alternating), so a machine that drifts in speed shifts
both alike; the table gives the first call (compilation included) and the median and every pair.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console
from rich.table import Table

from benchmarks.output import write_json

MODES = ("whole episodes", "physics only")


def measure(agent: str, preset: str, pairs: int) -> dict:
    from mjx_push import encoder as enc
    from mjx_push.train import presets
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import run_adapter

    cfg = presets.make(agent, preset, 0)
    adapter = run_adapter(cfg, enc.load(None))
    runners = {
        "whole episodes": Runner(make_train(cfg.train, adapter)),
        "physics only": Runner(make_train(cfg.train, dataclasses.replace(adapter, one_device=None))),
    }
    splits = [r.trainer.rollout_split for r in runners.values()]
    if splits != ["episodes", "physics"]:
        raise SystemExit(
            f"{len(jax.devices())} device(s), {cfg.train.loop.num_envs} environments: the rollouts split by {splits}"
        )
    actor = runners["whole episodes"].init(jax.random.PRNGKey(0)).sac.actor_params
    flags = (jnp.asarray(False), jnp.asarray(False), jnp.asarray(np.zeros(cfg.train.loop.num_envs, bool)))

    def timed(mode: str, seed: int) -> float:
        t0 = time.perf_counter()
        jax.block_until_ready(runners[mode].rollout(actor, jax.random.PRNGKey(seed), *flags))
        return time.perf_counter() - t0

    rows = {mode: {"first_call_s": timed(mode, 1), "rollout_s": []} for mode in MODES}
    for i in range(pairs):
        for mode in MODES if i % 2 == 0 else MODES[::-1]:
            rows[mode]["rollout_s"].append(timed(mode, 10 + i))
    for r in rows.values():
        r["median_s"] = float(np.median(r["rollout_s"]))
    return {
        "agent": agent,
        "preset": preset,
        "num_envs": cfg.train.loop.num_envs,
        "devices": len(jax.devices()),
        "rows": rows,
    }


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--agent", default="egru")
    p.add_argument("--preset", default="cpu-long")
    p.add_argument("--pairs", type=int, default=3)
    p.add_argument("--out", type=Path, default=Path("outputs/bench_rollout_split.json"))
    a = p.parse_args(argv)
    if a.pairs < 1:
        raise SystemExit(f"--pairs must be at least 1, got {a.pairs}")
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    result = measure(a.agent, a.preset, a.pairs)
    base = result["rows"]["physics only"]["median_s"]
    table = Table(title=f"training rollout, {a.agent} {a.preset}, {result['devices']} host devices")
    for col in ("split", "first call s", "median s", "x", "each pair s"):
        table.add_column(col, justify="right")
    for mode, r in result["rows"].items():
        each = " ".join(f"{t:.1f}" for t in r["rollout_s"])
        table.add_row(mode, f"{r['first_call_s']:.1f}", f"{r['median_s']:.1f}", f"{base / r['median_s']:.2f}", each)
    Console(width=120).print(table)
    write_json(a.out, result)


if __name__ == "__main__":
    main()

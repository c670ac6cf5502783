"""A one-device run's training rollout on several host devices, split three ways: a program per shape
group on devices of its own (the default: `mjx_push.train.rollout.make_group_collect`), each device
running its share of every group (`make_split_collect`, the default before, and still a one-shape
run's), and the physics only (the adapter's batch over the devices, joined every tick; what runs when
the adapter offers no one-device twin).

    python -m benchmarks.rollout_split [--agent egru] [--preset cpu-long] [--pairs 3] [--modes ...] [--out OUT.json]

The rollouts are compiled in one process from the preset's run configuration (the same episodes), then
timed in `--pairs` interleaved rounds (the order alternating), so a machine that drifts in speed shifts
all alike; the table gives the first call (compilation included), the median and every round, and
each split's speed against the physics-only one's (or the last mode given).
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

# Trainer.rollout_split's names, and what each means.
MODES = {"groups": "a program per shape group", "episodes": "shares of every group", "physics": "physics only"}


def measure(agent: str, preset: str, pairs: int, modes: tuple[str, ...] = tuple(MODES)) -> dict:
    from mjx_push import encoder as enc
    from mjx_push.train import presets
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import run_adapter

    cfg = presets.make(agent, preset, 0)
    adapter = run_adapter(cfg, enc.load(None))
    no_groups = lambda a, group=None: None if group is not None else adapter.one_device(adapter)  # noqa: E731
    adapters = {
        "groups": adapter,
        "episodes": dataclasses.replace(adapter, one_device=no_groups),
        "physics": dataclasses.replace(adapter, one_device=None),
    }
    runners = {mode: Runner(make_train(cfg.train, adapters[mode])) for mode in modes}
    splits = [r.trainer.rollout_split for r in runners.values()]
    if splits != list(modes):
        raise SystemExit(
            f"{len(jax.devices())} device(s), {cfg.train.loop.num_envs} environments: the rollouts split by {splits}"
        )
    actor = runners[modes[0]].init(jax.random.PRNGKey(0)).sac.actor_params
    flags = (jnp.asarray(False), jnp.asarray(False), jnp.asarray(np.zeros(cfg.train.loop.num_envs, bool)))

    def timed(mode: str, seed: int) -> float:
        t0 = time.perf_counter()
        jax.block_until_ready(runners[mode].rollout(actor, jax.random.PRNGKey(seed), *flags))
        return time.perf_counter() - t0

    rows = {mode: {"first_call_s": timed(mode, 1), "rollout_s": []} for mode in modes}
    for i in range(pairs):
        for mode in modes if i % 2 == 0 else modes[::-1]:
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
    p.add_argument("--pairs", type=int, default=3, help="rounds of timed rollouts, one of each split per round")
    p.add_argument("--modes", nargs="+", choices=list(MODES), default=list(MODES), help="the splits to compare")
    p.add_argument("--out", type=Path, default=Path("outputs/bench_rollout_split.json"))
    a = p.parse_args(argv)
    if a.pairs < 1:
        raise SystemExit(f"--pairs must be at least 1, got {a.pairs}")
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    result = measure(a.agent, a.preset, a.pairs, tuple(a.modes))
    base = result["rows"][a.modes[-1]]["median_s"]
    table = Table(title=f"training rollout, {a.agent} {a.preset}, {result['devices']} host devices")
    for col in ("split", "first call s", "median s", "x", "each round s"):
        table.add_column(col, justify="right")
    for mode, r in result["rows"].items():
        each = " ".join(f"{t:.1f}" for t in r["rollout_s"])
        table.add_row(
            f"{mode} ({MODES[mode]})",
            f"{r['first_call_s']:.1f}",
            f"{r['median_s']:.1f}",
            f"{base / r['median_s']:.2f}",
            each,
        )
    Console(width=120).print(table)
    write_json(a.out, result)


if __name__ == "__main__":
    main()

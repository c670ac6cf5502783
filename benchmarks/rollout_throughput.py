"""Rollout throughput of the learner on the MJX pushing task: lockstep vs the substep scheduler.

    python -m benchmarks.rollout_throughput [--num-envs 10] [--chunks 0 25] [--repeats 2]
        [--agent vpm] [--out outputs/bench_rollout.json]

For each environment count and scheduler chunk (0 = lockstep: every env step waits for the slowest
environment's a_s substeps) it compiles the training rollout of the cpu preset (one full 50-step
episode per environment, uniform random actions as in the warm-up, and the untrained policy's
stochastic actions), then times `--repeats` rollouts. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
import jax.numpy as jnp
from rich.console import Console
from rich.table import Table

from mjx_push import encoder as enc
from mjx_push.train import presets
from mjx_push.train.config import AGENT_KINDS
from mjx_push.train.loop import make_train
from mjx_push.train.push_task import make_push_adapter


def measure(num_envs: int, chunk: int, repeats: int, agent: str) -> list[dict]:
    cfg = presets.make(agent, "cpu", 0)
    loop = dataclasses.replace(cfg.train.loop, num_envs=num_envs)
    trainer = make_train(
        dataclasses.replace(cfg.train, loop=loop), make_push_adapter(cfg.env, enc.load(None), substep_chunk=chunk)
    )
    actor = trainer.init(jax.random.PRNGKey(0)).sac.actor_params
    rollout = jax.jit(trainer.rollout)
    rows = []
    for label, random_actions in (("random actions", True), ("untrained policy", False)):
        args = lambda i: (actor, jax.random.PRNGKey(i), jnp.asarray(random_actions), jnp.asarray(False))  # noqa: E731
        t0 = time.perf_counter()
        jax.block_until_ready(rollout(*args(0)))
        first = time.perf_counter() - t0
        times = []
        for i in range(repeats):
            t0 = time.perf_counter()
            episodes, _ = jax.block_until_ready(rollout(*args(i + 1)))
            times.append(time.perf_counter() - t0)
        a_s = episodes["action"][..., 2]
        substeps = (
            jnp.floor((jnp.clip(a_s, -1, 1) + 1) / 2 * (cfg.env.substeps[1] - cfg.env.substeps[0]))
            + cfg.env.substeps[0]
        )
        best = min(times)
        rows.append(
            {
                "num_envs": num_envs,
                "chunk": chunk,
                "actions": label,
                "first_call_s": first,
                "rollout_s": best,
                "env_steps_per_s": num_envs * cfg.env.episode_length / best,
                "substeps_per_env_step": float(substeps.mean()),
            }
        )
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--num-envs", type=int, nargs="+", default=[10])
    p.add_argument("--chunks", type=int, nargs="+", default=[0, 50])
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--agent", default="vpm", choices=AGENT_KINDS)
    p.add_argument("--out", type=Path, default=Path("outputs/bench_rollout.json"))
    a = p.parse_args(argv)
    rows = []
    for n in a.num_envs:
        for c in a.chunks:
            rows += measure(n, c, a.repeats, a.agent)
    base = {(r["num_envs"], r["actions"]): r["rollout_s"] for r in rows if r["chunk"] == 0}
    table = Table(title=f"rollout throughput ({jax.default_backend()}, {a.agent}, 50-step episodes)")
    for col in ("envs", "chunk", "actions", "first call s", "rollout s", "env steps/s", "mean substeps", "speed-up"):
        table.add_column(col, justify="right")
    for r in rows:
        ref = base.get((r["num_envs"], r["actions"]))
        r["speedup_vs_lockstep"] = ref / r["rollout_s"] if ref else None
        table.add_row(
            str(r["num_envs"]),
            str(r["chunk"] or "lockstep"),
            r["actions"],
            f"{r['first_call_s']:.1f}",
            f"{r['rollout_s']:.2f}",
            f"{r['env_steps_per_s']:.1f}",
            f"{r['substeps_per_env_step']:.0f}",
            f"{r['speedup_vs_lockstep']:.2f}x" if r["speedup_vs_lockstep"] else "-",
        )
    Console(width=140).print(table)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(
        json.dumps({"machine": f"{platform.machine()}, jax {jax.default_backend()}", "rows": rows}, indent=2) + "\n"
    )
    print(f"wrote {a.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()

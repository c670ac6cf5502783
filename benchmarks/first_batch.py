"""Where a run's first batch goes, cold: each program's tracing, lowering and XLA compilation (JAX's
own duration events, `jax.monitoring`), the rollout and the updates of the first two batches.

    python -m benchmarks.first_batch [--agent vpm] [--preset cpu] [--shape any] [--threads] [--out OUT.json]

The persistent compilation cache is turned off in this process, so every program compiles. A batch of
both shapes on 2 host devices runs a rollout program per shape group (`run_envs`), each traced and
compiled in a thread of its own: their seconds are summed over the threads, which overlap, so the
batch's wall time is the figure to compare. `--shape cylinder` (or `cuboid`, ...) trains one shape
group. `--threads` also compiles the rollouts of two one-shape runs (cylinder, cuboid), lowered first,
one after the other and again in two threads: whether a second core can take one of them in the same
process (the sequential round first: a warm-up, if any, favours the threads).
"""

from __future__ import annotations

import argparse
import collections
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console
from rich.table import Table

from benchmarks.jax_events import COMPILE_EVENT, LOWER_EVENT, TRACE_EVENT
from benchmarks.output import write_json

PHASES = {TRACE_EVENT: "trace_s", LOWER_EVENT: "lower_s", COMPILE_EVENT: "compile_s"}


def _runner(agent: str, preset: str, shape: str):
    from mjx_push import encoder as enc
    from mjx_push.train import presets
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import run_adapter

    cfg = presets.with_overrides(presets.make(agent, preset, 0), {"env.objects.shape": shape})
    return cfg, Runner(make_train(cfg.train, run_adapter(cfg, enc.load(None))))


def first_batches(agent: str, preset: str, shape: str) -> dict:
    """Two batches of a fresh run; the programs compiled in each, by name and phase."""
    events: dict = collections.defaultdict(float)
    current = {"batch": "setup"}
    lock = threading.Lock()  # the shape groups' programs report from two threads

    def on_event(event, secs, **kw):
        if event in PHASES and secs > 0.05:
            name = str(kw.get("fun_name", "?")).removeprefix("jit(").removesuffix(")")
            with lock:
                events[(current["batch"], name, PHASES[event])] += secs

    jax.monitoring.register_event_duration_secs_listener(on_event)
    try:
        cfg, runner = _runner(agent, preset, shape)
        state = runner.init(jax.random.PRNGKey(0))
        batches = []
        for i in range(2):
            current["batch"] = f"batch {i + 1}"
            t0 = time.perf_counter()
            state, metrics = runner.iteration(state)
            batches.append(
                {
                    "wall_s": time.perf_counter() - t0,
                    "rollout_s": float(metrics["rollout_s"]),
                    "learn_s": float(metrics["learn_s"]),
                }
            )
    finally:
        jax.monitoring.unregister_event_duration_listener(on_event)
    programs: dict = {}
    for (batch, name, phase), secs in events.items():
        programs.setdefault(f"{batch}: {name}", {"trace_s": 0.0, "lower_s": 0.0, "compile_s": 0.0})[phase] += secs
    big = {k: v for k, v in programs.items() if sum(v.values()) >= 1.0}
    return {"num_envs": cfg.train.loop.num_envs, "batches": batches, "programs": big}


def two_rollouts_in_threads(agent: str, preset: str) -> dict:
    """The rollouts of a cylinder-only and a cuboid-only run, lowered, then compiled one after the
    other; then lowered again (new runners: new programs for JAX) and compiled in two threads."""
    flags = lambda cfg: (  # noqa: E731
        jnp.asarray(False),
        jnp.asarray(False),
        jnp.asarray(np.zeros(cfg.train.loop.num_envs, bool)),
    )

    def lowered():
        out = []
        for shape in ("cylinder", "cuboid"):
            cfg, runner = _runner(agent, preset, shape)
            actor = runner.init(jax.random.PRNGKey(0)).sac.actor_params
            args = (actor, jax.random.PRNGKey(1), *flags(cfg))
            if runner.shared_episodes:
                args += ({**runner.eval_chunks()[0], "use": np.asarray(False)},)
            fn = runner.trainer.rollout
            out.append(jax.jit(fn).lower(*args))
        return out

    lows = lowered()
    t0 = time.perf_counter()
    for low in lows:
        low.compile()
    sequential = time.perf_counter() - t0
    lows = lowered()
    t0 = time.perf_counter()
    with ThreadPoolExecutor(len(lows)) as pool:
        for done in [pool.submit(low.compile) for low in lows]:
            done.result()  # a failed compilation raises here, not only in its thread
    return {"sequential_s": sequential, "two_threads_s": time.perf_counter() - t0}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--agent", default="vpm")
    p.add_argument("--preset", default="cpu")
    p.add_argument("--shape", default="any", help="env.objects.shape (any: both shape groups)")
    p.add_argument("--threads", action="store_true", help="also compile two one-shape rollouts in two threads")
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    xla.use_cpu_devices()
    # Cold by construction: a cache set in the environment (JAX_COMPILATION_CACHE_DIR) would turn
    # compilations into loads, and the threaded round into loads of what the sequential round wrote.
    jax.config.update("jax_enable_compilation_cache", False)
    res = first_batches(a.agent, a.preset, a.shape)
    table = Table(title=f"{a.agent} / {a.preset}, shape {a.shape}: programs compiled (>= 1 s)")
    for col in ("program", "trace s", "lower s", "compile s"):
        table.add_column(col, justify="left" if col == "program" else "right")
    for name, v in res["programs"].items():
        table.add_row(name, f"{v['trace_s']:.1f}", f"{v['lower_s']:.1f}", f"{v['compile_s']:.1f}")
    console = Console()
    console.print(table)
    for i, b in enumerate(res["batches"], 1):
        console.print(f"batch {i}: {b['wall_s']:.1f} s (rollout {b['rollout_s']:.1f}, updates {b['learn_s']:.1f})")
    payload = {"agent": a.agent, "preset": a.preset, "shape": a.shape, "devices": len(jax.devices()), **res}
    if a.threads:
        payload["two_rollouts"] = two_rollouts_in_threads(a.agent, a.preset)
        t = payload["two_rollouts"]
        console.print(
            f"two one-shape rollouts compiled: one after the other {t['sequential_s']:.1f} s, "
            f"in two threads {t['two_threads_s']:.1f} s"
        )
    if a.out is not None:
        write_json(a.out, payload)


if __name__ == "__main__":
    main()

"""Data-parallel training speed on this machine: the learner's SAC updates/s and the rollout's env steps/s
with the run on 1 device and spread over D host devices (`loop.data_parallel`, train/data_parallel.py).

    python -m benchmarks.data_parallel [--agent egru] [--preset cpu-long] [--devices 1 2] [--batches 3]
                                       [--no-rollout] [--out outputs/bench_data_parallel.json]

The learner: the preset's (networks, batch sizes, updates per episode batch, replay), fed with
synthetic episodes of the pushing scene's shapes (its cost does not depend on what they hold), so it
times `Runner.learn` alone: one call to compile and fill replay, then `--batches` timed calls, each the
updates of one episode batch. The rollout: one episode of the preset's `num_envs` pushing-scene
environments through `Runner.rollout` (policy actions), compiled once, then timed twice. The global
batch sizes are the same at every device count; with D devices each device runs 1/D of them. Prints a
table and writes JSON. On a CPU the host devices share the cores (`mjx_push.xla.use_cpu_devices`): the
ratio says what splitting buys there; on a GPU node each device is a chip. The 1-device row is the
default run (`mjx-push train`): its rollout already uses every core, its learner one device.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from benchmarks.output import write_json
from mjx_push import xla


def synthetic_episodes(cfg, episode_len: int, priv_dim: int, key):
    """A batch of `num_envs` valid demonstration episodes of `episode_len` steps (the task's) with random
    contents, as the learner stores them."""
    import jax
    import jax.numpy as jnp

    from mjx_push.train import replay

    loop = cfg.loop
    spec = replay.episode_spec(
        episode_len, 3, priv_dim if cfg.agent.critic_obs == "privileged" else 0, cfg.demo.enabled
    )
    out = {}
    for i, (name, (shape, dtype)) in enumerate(sorted(spec.items())):
        shape = (loop.num_envs,) + tuple(shape)
        if dtype == jnp.bool_:
            out[name] = jnp.ones(shape, bool)
        else:
            out[name] = jax.random.uniform(jax.random.fold_in(key, i), shape, dtype, -1.0, 1.0)
    return out


def measure(agent: str, preset: str, devices: int, batches: int, rollout: bool) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from mjx_push import encoder as enc
    from mjx_push.train import presets
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import PRIV_DIM, run_adapter

    run = presets.make(agent, preset)
    cfg = dataclasses.replace(
        run.train, loop=dataclasses.replace(run.train.loop, data_parallel=devices, warmup_env_steps=0)
    )
    # One device is the default run: the learner on one device, the rollout's environments split over
    # every host device (as `mjx-push train` does); data parallel steps each device's share on it.
    adapter = run_adapter(dataclasses.replace(run, train=cfg), enc.load(None))
    runner = Runner(make_train(cfg, adapter))
    T = run.env.episode_length
    ts = runner.init(jax.random.PRNGKey(0))
    row = {"devices": devices, "num_envs": cfg.loop.num_envs, "updates_per_batch": cfg.loop.updates_per_iteration(T)}
    t0 = time.perf_counter()
    ts, m = jax.block_until_ready(
        runner.learn(ts, synthetic_episodes(cfg, T, PRIV_DIM, jax.random.PRNGKey(1)), jax.random.PRNGKey(100))
    )
    row["learn_compile_s"] = time.perf_counter() - t0
    assert bool(m["learning"]), "the timed batches must run their updates"
    times = []
    for b in range(batches):
        eps = synthetic_episodes(cfg, T, PRIV_DIM, jax.random.PRNGKey(2 + b))
        t0 = time.perf_counter()
        ts, m = jax.block_until_ready(runner.learn(ts, eps, jax.random.PRNGKey(101 + b)))
        times.append(time.perf_counter() - t0)
    row["updates_per_s"] = cfg.loop.updates_per_iteration(T) / float(np.median(times))
    if rollout:
        flags = (jnp.asarray(False), jnp.asarray(False), np.zeros(cfg.loop.num_envs, bool))
        t0 = time.perf_counter()
        jax.block_until_ready(runner.rollout(ts.sac.actor_params, jax.random.PRNGKey(3), *flags))
        row["rollout_compile_s"] = time.perf_counter() - t0
        times = []
        for r in range(2):
            t0 = time.perf_counter()
            jax.block_until_ready(runner.rollout(ts.sac.actor_params, jax.random.PRNGKey(4 + r), *flags))
            times.append(time.perf_counter() - t0)
        row["env_steps_per_s"] = cfg.loop.env_steps_per_iteration(T) / float(np.median(times))
    return row


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--agent", default="egru")
    p.add_argument("--preset", default="cpu-long")
    p.add_argument("--devices", type=int, nargs="+", default=[1, 2])
    p.add_argument("--batches", type=int, default=3)
    p.add_argument("--no-rollout", action="store_true")
    p.add_argument("--out", type=Path, default=Path("outputs/bench_data_parallel.json"))
    a = p.parse_args(argv)
    xla.use_cpu_devices(max(a.devices))
    import jax
    from rich.console import Console
    from rich.table import Table

    rows = [measure(a.agent, a.preset, d, a.batches, not a.no_rollout) for d in a.devices]
    base = rows[0]
    for r in rows:
        r["updates_speedup"] = r["updates_per_s"] / base["updates_per_s"]
        if "env_steps_per_s" in r:
            r["env_steps_speedup"] = r["env_steps_per_s"] / base["env_steps_per_s"]
    table = Table(title=f"data parallel: {a.agent} {a.preset} on {jax.device_count()} {jax.default_backend()} devices")
    for col in ("devices", "learn compile s", "updates/s", "x", "rollout compile s", "env steps/s", "x"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            str(r["devices"]),
            f"{r['learn_compile_s']:.0f}",
            f"{r['updates_per_s']:.0f}",
            f"{r['updates_speedup']:.2f}",
            f"{r.get('rollout_compile_s', float('nan')):.0f}",
            f"{r.get('env_steps_per_s', float('nan')):.1f}",
            f"{r.get('env_steps_speedup', float('nan')):.2f}",
        )
    Console().print(table)
    write_json(a.out, {"agent": a.agent, "preset": a.preset, "rows": rows})


if __name__ == "__main__":
    main()

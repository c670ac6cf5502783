"""The learner's share of a training batch: one `Runner.learn` call (the updates of one episode batch)
of an agent at a preset, timed at chosen env steps, so each phase of a schedule is measured (with the
teacher, while it leaves, after it has gone, after the anchor's release).

    python -m benchmarks.learner_speed [--agent egru] [--preset teacher-free]
                                       [--at 40000 72000 88000 112000] [--repeats 3]
                                       [--out outputs/bench_learner_speed.json]

The replay buffer holds synthetic episodes of the pushing scene's shapes (the learner's cost does not
depend on what they hold; `benchmarks.data_parallel.synthetic_episodes`), half of them demonstrations.
Each row: the first call (compilation included) and the median of `--repeats` timed calls. Prints a
table and writes JSON. Run it alone on the machine: other processes on the cores change the figures.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from benchmarks.output import write_json
from mjx_push import xla


def measure(agent: str, preset: str, at: int, repeats: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from benchmarks.data_parallel import synthetic_episodes
    from mjx_push import encoder as enc
    from mjx_push.train import presets, replay
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import PRIV_DIM, make_push_adapter

    run = presets.make(agent, preset)
    cfg, T = run.train, run.env.episode_length
    runner = Runner(make_train(cfg, make_push_adapter(run.env, enc.load(None), expert_config=run.expert)))
    ts = runner.init(jax.random.PRNGKey(0))
    buffer = ts.buffer
    for i in range(4):  # past the batch size, demonstrations and the agent's own episodes both
        eps = synthetic_episodes(cfg, T, PRIV_DIM, jax.random.PRNGKey(10 + i))
        buffer = replay.add(buffer, {**eps, "demo": jnp.full(eps["valid"].shape, i % 2 == 0)})
    # The batch about to be learned ends at `at` env steps: the schedule's weights are those of that batch.
    ts = ts.replace(buffer=buffer, env_steps=jnp.asarray(at - cfg.loop.env_steps_per_iteration(T), jnp.int32))
    times = []
    for r in range(repeats + 1):
        eps = synthetic_episodes(cfg, T, PRIV_DIM, jax.random.PRNGKey(100 + r))
        step = int(ts.env_steps)  # the state is donated to the call
        t0 = time.perf_counter()
        ts, m = jax.block_until_ready(runner.learn(ts, eps, jax.random.PRNGKey(200 + r)))
        times.append(time.perf_counter() - t0)
        ts = ts.replace(env_steps=jnp.asarray(step, jnp.int32))  # every call learns the same phase
        assert bool(m["learning"]), "the timed batches must run their updates"
    return {
        "agent": agent,
        "preset": preset,
        "env_steps": at,
        "teacher_scale": float(m["demo/teacher_scale"]),
        "anchor_scale": float(m["demo/anchor_scale"]),
        "updates": cfg.loop.updates_per_iteration(T),
        "first_call_s": times[0],
        "learn_s": float(np.median(times[1:])),
        "ms_per_update": 1000 * float(np.median(times[1:])) / cfg.loop.updates_per_iteration(T),
    }


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--agent", default="egru")
    p.add_argument("--preset", default="teacher-free")
    p.add_argument("--at", type=int, nargs="+", default=[40_000, 72_000, 88_000, 112_000])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", type=Path, default=Path("outputs/bench_learner_speed.json"))
    a = p.parse_args(argv)
    xla.use_cpu_devices()
    import jax
    from rich.console import Console
    from rich.table import Table

    rows = [measure(a.agent, a.preset, at, a.repeats) for at in a.at]
    table = Table(title=f"learner: {a.agent} {a.preset}, one batch's updates, {jax.default_backend()}")
    for col in ("env steps", "teacher", "anchor", "updates", "first call s", "learn s", "ms/update"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            f"{r['env_steps']:,}",
            f"{r['teacher_scale']:.2f}",
            f"{r['anchor_scale']:.2f}",
            str(r["updates"]),
            f"{r['first_call_s']:.1f}",
            f"{r['learn_s']:.2f}",
            f"{r['ms_per_update']:.1f}",
        )
    Console().print(table)
    write_json(a.out, {"rows": rows})


if __name__ == "__main__":
    main()

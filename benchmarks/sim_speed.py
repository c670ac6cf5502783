"""MJX against CPU MuJoCo on the same episodes, side by side: useful substeps per second on this machine.

    python -m benchmarks.sim_speed [--preset cpu] [--num-envs 32] [--steps 20] [--chunk 50]
                                   [--cores N] [--out outputs/bench_sim_speed.json]

Both simulators run the same `--num-envs` objects (drawn once by the MJX batch) and the same
`--steps` uniform random actions per environment, a_s included, under the preset's environment:

- CPU MuJoCo: the project's CPU environment (`mjx_push.export.cpu_env.CpuPushEnv`, C `mj_step` with the NumPy
  controller at every substep, analytic masks), the environments dealt out to `--cores` worker
  processes (default: every core this process may use), timed from a start signal to the last worker's
  end; the per-core rate is the same work in one process.
- MJX: `mjx_push.batch.PushBatch` in one process, on one device and split over all host devices
  (`mjx_push.xla`), stepped two ways: "lockstep" (`step`: a batched step lasts as long as its slowest
  environment's a_s) and "scheduled" (`begin`/`advance`/`ready`/`finish` in chunks of `--chunk`
  substeps, each environment taking its next action when its own step ends, as the training rollout
  does). Each is compiled first (the time is reported) and then timed.

"Useful" substeps are the ones the actions asked for (the sum of the decoded a_s); the ratio in the
last column is MJX's useful substeps/s over CPU MuJoCo's on the same cores. Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console
from rich.table import Table

from mjx_push.export.cpu_env import CpuPushEnv
from mjx_push.export.cpu_env import decode_substeps as cpu_decode_substeps
from mjx_push.batch import PushBatch
from mjx_push.env import decode_substeps
from mjx_push.xla import cpu_device_count
from mjx_push.train import presets


def _episode_inputs(batch: PushBatch, key: jax.Array, steps: int):
    state = batch.jit_reset(key)
    actions = jax.random.uniform(jax.random.fold_in(key, 1), (steps, batch.num_envs, 3), minval=-1.0, maxval=1.0)
    return state, actions


def _mjx_runners(batch: PushBatch, steps: int, chunk: int):
    """Jitted (state, actions [T, N, 3]) -> final state, for lockstep and scheduled stepping."""

    def lockstep(state, actions):
        return jax.lax.fori_loop(0, steps, lambda t, s: batch.step(s, actions[t]), state)

    def scheduled(state, actions):
        n = batch.num_envs
        everyone = jnp.ones((n,), bool)
        state = batch.begin(state, actions[0], everyone)

        def body(c):
            s, t = c
            s = batch.advance(s, chunk)
            done = batch.ready(s) & (t < steps)
            s = batch.finish(s, done)
            t = t + done.astype(jnp.int32)
            more = done & (t < steps)
            s = batch.begin(s, actions[jnp.minimum(t, steps - 1), jnp.arange(n)], more)
            return s, t

        state, _ = jax.lax.while_loop(lambda c: jnp.any(c[1] < steps), body, (state, jnp.zeros((n,), jnp.int32)))
        return state

    return {"lockstep": jax.jit(lockstep), "scheduled": jax.jit(scheduled)}


def measure_mjx(
    env_config,
    num_envs: int,
    steps: int,
    chunk: int,
    max_devices: int | None,
    key,
    modes: tuple[str, ...] = ("lockstep", "scheduled"),
) -> list[dict]:
    batch = PushBatch(env_config, num_envs, max_devices=max_devices)
    state, actions = _episode_inputs(batch, key, steps)
    useful = int(jnp.sum(decode_substeps(actions[..., 2], env_config.substeps)))
    rows = []
    runners = _mjx_runners(batch, steps, chunk)
    for mode in modes:
        fn = runners[mode]
        t0 = time.perf_counter()
        jax.block_until_ready(fn(state, actions))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(state, actions))
        dt = time.perf_counter() - t0
        rows.append(
            {
                "simulator": "MJX",
                "mode": mode,
                "devices": batch.num_devices,
                "compile_s": first - dt,
                "wall_s": dt,
                "useful_substeps": useful,
                "useful_substeps_per_s": useful / dt,
                "env_steps_per_s": num_envs * steps / dt,
                "invalid_steps": int(jnp.sum(out.info["invalid_count"])),
            }
        )
    return rows


# --- CPU MuJoCo workers --------------------------------------------------------------------------------
def _cpu_work(job) -> float:
    """Run a share of the episodes in this process; returns the seconds it took (construction excluded)."""
    env_config, episodes, start = job
    env = CpuPushEnv(env_config, mask_source="analytic")
    for geom, params, _ in episodes:  # build each shape's model before the clock starts
        env.reset(seed=0, params=params, geom_type=geom)
    if start is not None:
        start.wait()
    t0 = time.perf_counter()
    for i, (geom, params, acts) in enumerate(episodes):
        env.reset(seed=i, params=params, geom_type=geom)
        for a in acts:
            env.step(a)
    return time.perf_counter() - t0


def measure_cpu(env_config, episodes: list, cores: int) -> list[dict]:
    useful = sum(cpu_decode_substeps(a[2], env_config.substeps) for _, _, acts in episodes for a in acts)
    steps = sum(len(acts) for _, _, acts in episodes)
    rows = []
    one = _cpu_work((env_config, episodes, None))
    rows.append(
        {
            "simulator": "CPU MuJoCo",
            "mode": "1 process",
            "devices": 1,
            "compile_s": 0.0,
            "wall_s": one,
            "useful_substeps": useful,
            "useful_substeps_per_s": useful / one,
            "env_steps_per_s": steps / one,
            "invalid_steps": None,
        }
    )
    if cores > 1:
        # Spawned workers (no forked JAX runtime); each builds its environment, then all start together.
        ctx = mp.get_context("spawn")
        with ctx.Manager() as manager:
            start = manager.Barrier(cores + 1)
            shares = [(env_config, episodes[i::cores], start) for i in range(cores)]
            with ctx.Pool(cores) as pool:
                res = pool.map_async(_cpu_work, shares)
                start.wait()
                t0 = time.perf_counter()
                res.get()
                wall = time.perf_counter() - t0
        rows.append(
            {
                "simulator": "CPU MuJoCo",
                "mode": f"{cores} processes",
                "devices": cores,
                "compile_s": 0.0,
                "wall_s": wall,
                "useful_substeps": useful,
                "useful_substeps_per_s": useful / wall,
                "env_steps_per_s": steps / wall,
                "invalid_steps": None,
            }
        )
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="cpu", choices=presets.PRESETS)
    p.add_argument("--num-envs", type=int, default=32)
    p.add_argument("--steps", type=int, default=20, help="environment steps per environment")
    p.add_argument("--chunk", type=int, default=50, help="substeps per tick of the scheduled mode")
    p.add_argument("--cores", type=int, default=cpu_device_count(), help="CPU MuJoCo worker processes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("outputs/bench_sim_speed.json"))
    a = p.parse_args(argv)
    for name in ("num_envs", "steps", "chunk", "cores"):
        if getattr(a, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(a, name)}")
    env_config = presets.make("vpm", a.preset, a.seed).env
    key = jax.random.PRNGKey(a.seed)
    console = Console(width=150)

    rows = []
    for max_devices in (1, None):
        if max_devices is None and len(jax.devices()) == 1:
            break
        console.print(f"MJX on {'one device' if max_devices == 1 else 'all devices'} ...")
        rows += measure_mjx(env_config, a.num_envs, a.steps, a.chunk, max_devices, key)

    # The same objects and actions for CPU MuJoCo.
    batch = PushBatch(env_config, a.num_envs, max_devices=1)
    state, actions = _episode_inputs(batch, key, a.steps)
    params = state.cat(lambda s: s.info["params"])
    geoms = [batch.geom_types[int(i)] for i in np.asarray(batch.shape_ids)]
    acts = np.asarray(actions, np.float64)
    episodes = [(geoms[i], jax.tree.map(lambda x: np.asarray(x[i]), params), acts[:, i]) for i in range(a.num_envs)]
    console.print(f"CPU MuJoCo on 1 and {a.cores} processes ...")
    rows += measure_cpu(env_config, episodes, a.cores)

    cpu_rate = {r["devices"]: r["useful_substeps_per_s"] for r in rows if r["simulator"] == "CPU MuJoCo"}
    c_all = cpu_rate[max(cpu_rate)]
    table = Table(
        title=f"MJX vs CPU MuJoCo, {a.preset} preset, {a.num_envs} envs x {a.steps} steps, "
        f"{platform.machine()} {os.cpu_count()} cores ({jax.default_backend()})"
    )
    for col in (
        "simulator",
        "mode",
        "devices",
        "compile s",
        "wall s",
        "useful substeps/s",
        "env steps/s",
        f"vs CPU MuJoCo ({max(cpu_rate)} cores)",
    ):
        table.add_column(col, justify="right")
    for r in rows:
        r["ratio_vs_cpu_mujoco_all_cores"] = r["useful_substeps_per_s"] / c_all
        table.add_row(
            r["simulator"],
            r["mode"],
            str(r["devices"]),
            f"{r['compile_s']:.1f}",
            f"{r['wall_s']:.2f}",
            f"{r['useful_substeps_per_s']:,.0f}",
            f"{r['env_steps_per_s']:.1f}",
            f"{r['ratio_vs_cpu_mujoco_all_cores']:.2f}",
        )
    console.print(table)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(
        json.dumps(
            {
                "machine": f"{platform.machine()}, {os.cpu_count()} cores",
                "backend": jax.default_backend(),
                "host_devices": len(jax.devices()),
                "args": {k: str(v) for k, v in vars(a).items()},
                "rows": rows,
            },
            indent=2,
        )
        + "\n"
    )
    console.print(f"wrote {a.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()

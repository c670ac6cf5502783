"""Where a training rollout's time goes: the phases of one scheduler tick of a shape group's program,
timed apart on one device (one core's share of a batch on a CPU).

    python -m benchmarks.tick_phases [--agent vpm] [--preset cpu] [--envs 16] [--repeats 20]
                                     [--out outputs/bench_tick_phases.json]

A rollout (`mjx_push.train.rollout.make_run_envs`, scheduled) repeats ticks: every environment
advances `DEFAULT_SUBSTEP_CHUNK` substeps of physics (`advance`: `mjx.step`, the task-space
controller and the per-substep counters), and on a tick where some environment's step is spent, the
whole group finishes its step (`finish`: validity, ground truth, the object mask and the encoder),
acts (`act`: the agent's actor; `expert`: the scripted expert's action, computed for every
environment where demonstrations are stored) and begins its next step (`begin`). Each phase is jitted
alone over `--envs` environments of one shape, at the preset's task, and timed as the median of
`--repeats` calls after one warm call. The last column is the share of a tick with a turn that the
physics takes; the rest is what any change to the other phases could at most win back. The two
groups run as programs of their own, so the faster group's device idles at the batch's end until
the slower one's episodes end. Prints a table, writes JSON. Run it alone on the machine.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from benchmarks.output import write_json
from mjx_push import xla


def _median_ms(fn, args, repeats: int) -> float:
    import jax

    jax.block_until_ready(fn(*args))  # compiles
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e3


def measure(agent: str, preset: str, shape: str, envs: int, repeats: int) -> dict:
    import jax
    import jax.numpy as jnp

    from mjx_push import encoder as enc
    from mjx_push.train import presets
    from mjx_push.train.networks import make_networks
    from mjx_push.train.push_task import DEFAULT_SUBSTEP_CHUNK, make_push_adapter

    run = presets.make(agent, preset)
    adapter = make_push_adapter(run.env, enc.load(None), expert_config=run.expert, max_devices=1, shapes=(shape,))
    sch = adapter.scheduler
    nets = make_networks(run.train.agent, priv_dim=adapter.priv_dim)
    actor_params, _ = nets.init(jax.random.PRNGKey(0), adapter.episode_len)
    state, obs, info = jax.jit(lambda k: adapter.reset(k, envs))(jax.random.PRNGKey(1))
    all_envs = jnp.ones((envs,), bool)

    def act(params, carry, obs, info, key):
        step_obs = {"ee_xy": obs["ee_xy"], "z_obj": obs["z_obj"], "z_goal": info["z_goal"]}
        return nets.act(params, carry, step_obs, key, jnp.asarray(False))

    action, carry = jax.jit(act)(actor_params, nets.init_carry(envs), obs, info, jax.random.PRNGKey(2))
    begin = jax.jit(lambda s, a: sch.begin(s, a, all_envs))
    state = begin(state, action)  # a step under way, as at every tick
    phases = {
        "advance": (jax.jit(lambda s: sch.advance(s, DEFAULT_SUBSTEP_CHUNK)), (state,)),
        "finish": (jax.jit(lambda s: sch.finish(s, all_envs)), (state,)),
        "act": (jax.jit(act), (actor_params, carry, obs, info, jax.random.PRNGKey(3))),
        "expert": (jax.jit(adapter.expert), (obs, info)),
        "begin": (begin, (state, action)),
    }
    ms = {name: _median_ms(fn, args, repeats) for name, (fn, args) in phases.items()}
    return {
        "agent": agent,
        "preset": preset,
        "shape": shape,
        "envs": envs,
        "substep_chunk": DEFAULT_SUBSTEP_CHUNK,
        "ms": ms,
        "substep_ms": ms["advance"] / DEFAULT_SUBSTEP_CHUNK,
        "physics_share_of_a_turn_tick": physics_share(ms),
    }


def physics_share(ms: dict) -> float:
    """The physics chunk's share of a tick on which the group's steps are finished and begun again."""
    return ms["advance"] / sum(ms[name] for name in ("advance", "finish", "act", "expert", "begin"))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--agent", default="vpm")
    ap.add_argument("--preset", default="cpu")
    ap.add_argument("--envs", type=int, default=16, help="environments of one shape on one device")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_tick_phases.json"))
    args = ap.parse_args(argv)
    if args.envs < 1:
        ap.error(f"--envs must be >= 1, got {args.envs}")
    if args.repeats < 1:
        ap.error(f"--repeats must be >= 1, got {args.repeats}")
    xla.use_cpu_devices()
    from rich.console import Console
    from rich.table import Table

    rows = [measure(args.agent, args.preset, shape, args.envs, args.repeats) for shape in ("box", "cylinder")]
    names = list(rows[0]["ms"])
    table = Table(title=f"one tick's phases, {args.agent} ({args.preset}), {args.envs} environments on one device, ms")
    for col in ("shape", *names, "physics share"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(r["shape"], *(f"{r['ms'][n]:.2f}" for n in names), f"{r['physics_share_of_a_turn_tick']:.0%}")
    Console(width=120).print(table)
    write_json(args.out, {"options": vars(args) | {"out": str(args.out)}, "rows": rows})


if __name__ == "__main__":
    main()

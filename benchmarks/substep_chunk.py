"""A training batch's rollout at several scheduler chunks (`--substep-chunk`), with the policy a run
has learned, interleaved so that a drifting machine drifts for every chunk alike.

    python -m benchmarks.substep_chunk [--policy RUN/best_policy.msgpack] [--chunks 50 200]
                                       [--rounds 3] [--out outputs/bench_substep_chunk.json]

Each chunk's rollout is the one a run compiles (`Runner.rollout`: the shape groups' programs on the
host devices), with the preset's share of the scripted expert's environments after its warm-up. It
is compiled and called once per chunk, then every round times one rollout of each chunk on the same
key. A chunk must not change the episodes: the script exits 1 when two chunks above 0 collected
different actions (beyond 1e-4). Lockstep (`0`) is reported, not checked: its episodes part from a
chunk's within a few steps (another order of float operations, and integer substep counts). Without `--policy` the
untrained actor acts; with one, the saved actor (and its run's configuration) acts, as in the
batches after the warm-up. Columns: the median rollout, env steps per second, and per shape group
the scheduler's ticks and turns (ticks on which some environment's step ended and the group
finished, encoded and acted for it) for the last round. Run it alone on the machine.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from benchmarks.output import write_json
from mjx_push import xla


def schedule(substeps: np.ndarray, chunk: int) -> tuple[int, int]:
    """(ticks, turns) of one group's rollout whose environments ask `substeps` [envs, T] per step:
    a tick advances every environment `chunk` substeps (0: lockstep, a step of the longest ask), a
    step ends on the first tick its substeps are spent, and the group runs until its slowest
    environment has run all T steps."""
    if chunk == 0:
        return substeps.shape[1], substeps.shape[1]
    ends = np.cumsum(-(-substeps // chunk), axis=1)
    return int(ends[:, -1].max()), int(np.unique(ends).size)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", type=Path, default=None, help="a run's saved policy (default: the untrained actor)")
    ap.add_argument("--agent", default="vpm", help="without --policy: the agent")
    ap.add_argument("--preset", default="cpu", help="without --policy: the preset")
    ap.add_argument("--chunks", type=int, nargs="+", default=[50, 200], help="substeps per tick (0: lockstep)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0, help="the rollouts' key")
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_substep_chunk.json"))
    a = ap.parse_args(argv)
    if a.rounds < 1 or any(c < 0 for c in a.chunks) or len(set(a.chunks)) != len(a.chunks):
        ap.error("--rounds must be >= 1 and --chunks distinct integers >= 0")

    xla.use_cpu_devices()
    import jax
    import jax.numpy as jnp
    from rich.console import Console
    from rich.table import Table

    from mjx_push import encoder as enc
    from mjx_push import task_rules
    from mjx_push.train import presets
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import run_adapter

    if a.policy is not None:
        from mjx_push.train.runs.policies import load_policy

        policy = load_policy(a.policy)
        run, actor, encoder = policy.config, policy.actor_params, policy.encoder_params
    else:
        run, actor, encoder = presets.make(a.agent, a.preset), None, enc.load(None)
    loop, cfg_env = run.train.loop, run.env
    runners = {c: Runner(make_train(run.train, run_adapter(run, encoder, c))) for c in a.chunks}
    first_runner = runners[a.chunks[0]]  # what every chunk shares: the initial actor, the expert's share, the groups
    if actor is None:
        actor = first_runner.init(jax.random.PRNGKey(0)).sac.actor_params
    # After the warm-up: the preset's share of the expert's environments, spread over the groups.
    expert = first_runner.expert_envs(loop.warmup_env_steps)
    key = jax.random.PRNGKey(a.seed)
    args = (actor, key, jnp.asarray(False), jnp.asarray(False), jnp.asarray(expert))

    first = {}
    for c, runner in runners.items():
        t0 = time.perf_counter()
        jax.block_until_ready(runner.rollout(*args))
        first[c] = time.perf_counter() - t0
    times = {c: [] for c in runners}
    actions = {}
    for _ in range(a.rounds):
        for c, runner in runners.items():
            t0 = time.perf_counter()
            episodes, _ = jax.block_until_ready(runner.rollout(*args))
            times[c].append(time.perf_counter() - t0)
            actions[c] = np.asarray(episodes["action"])
    ref = actions[next((c for c in a.chunks if c), a.chunks[0])]  # the first chunk above 0
    same = {c: bool(np.allclose(x, ref, atol=1e-4)) for c, x in actions.items()}
    # Where a rollout's episodes part from the first scheduled chunk's: the largest action difference, and how many
    # environments' actions differ by more than 1e-4 anywhere.
    gap = {c: float(np.abs(x - ref).max()) for c, x in actions.items()}
    parted = {c: int((np.abs(x - ref) > 1e-4).any(axis=(1, 2)).sum()) for c, x in actions.items()}

    substeps = np.asarray(task_rules.decode_substeps(ref[..., 2].astype(np.float32), cfg_env.substeps))
    groups = tuple(first_runner.adapter.groups(loop.num_envs) or (loop.num_envs,))
    bounds = np.cumsum((0,) + groups)
    rows = []
    for c in a.chunks:
        per_group = [schedule(substeps[lo:hi], c) for lo, hi in zip(bounds[:-1], bounds[1:])]
        med = statistics.median(times[c])
        rows.append(
            {
                "chunk": c,
                "first_call_s": first[c],
                "rollout_s": times[c],
                "median_s": med,
                "env_steps_per_s": loop.num_envs * cfg_env.episode_length / med,
                "ticks_turns_per_group": per_group,
                "same_actions_as_first_scheduled_chunk": same[c],
                "max_action_difference": gap[c],
                "environments_differing": parted[c],
            }
        )
    table = Table(title=f"a training batch's rollout by scheduler chunk ({jax.default_backend()}, {run.agent})")
    cols = (
        "chunk",
        "first call s",
        "rollout s (median)",
        "env steps/s",
        "ticks / turns per group",
        "same (envs apart)",
    )
    for col in cols:
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            str(r["chunk"] or "lockstep"),
            f"{r['first_call_s']:.1f}",
            f"{r['median_s']:.2f}",
            f"{r['env_steps_per_s']:.1f}",
            ", ".join(f"{t} / {u}" for t, u in r["ticks_turns_per_group"]),
            ("yes" if r["same_actions_as_first_scheduled_chunk"] else "NO") + f" ({r['environments_differing']})",
        )
    Console(width=140).print(table)
    write_json(
        a.out,
        {
            "policy": str(a.policy) if a.policy else None,
            "agent": run.agent,
            "num_envs": loop.num_envs,
            "expert_envs": int(expert.sum()),
            "substeps_per_step_mean": float(substeps.mean()),
            "rounds": a.rounds,
            "rows": rows,
        },
    )
    if not all(ok for c, ok in same.items() if c):
        raise SystemExit("two chunks collected different actions: the scheduler changed the episodes")


if __name__ == "__main__":
    main()

"""Whole training batches of an agent at a preset, timed as a run times them (`Runner.iteration`: the
rollout, then the learner's updates), at this checkout or at earlier commits, one after the other.

    python -m benchmarks.batch_speed [--agent egru] [--preset cpu-long] [--batches 6]
                                     [--data-parallel 1] [--commits fa0b29b HEAD]
                                     [--out outputs/bench_batch_speed.json]

Each row: the first batch (compilation included, no compilation cache) and the medians over the
batches that learn (after the warm-up) of the batch, its rollout and its updates. A commit other
than HEAD runs in a worktree and virtual environment of its own (OUT/../worktrees, as
`benchmarks.protocol_at_commit` builds them), with this file as its script, so rows compare the same
measurement across code. Run it alone on the machine: other processes on the cores change the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def measure(agent: str, preset: str, batches: int, data_parallel: int = 1) -> dict:
    """Run `batches` training batches from a fresh state in this process (whatever `mjx_push` this
    interpreter imports), the preset's run split over `data_parallel` devices; per batch its env
    steps, rollout_s, learn_s and wall_s."""
    import dataclasses

    from mjx_push import xla

    xla.use_cpu_devices()
    import jax

    import mjx_push
    from mjx_push import encoder as enc

    try:
        from mjx_push.train import presets
        from mjx_push.train.loop import Runner, make_train
        from mjx_push.train import push_task
    except ModuleNotFoundError:  # commits before the learner became mjx_push.train
        from train import presets  # type: ignore[no-redef]
        from train.loop import Runner, make_train  # type: ignore[no-redef]
        from train import push_task  # type: ignore[no-redef]

    run = presets.make(agent, preset)
    if data_parallel != 1:
        loop = dataclasses.replace(run.train.loop, data_parallel=data_parallel)
        run = dataclasses.replace(run, train=dataclasses.replace(run.train, loop=loop))
    if hasattr(push_task, "run_adapter"):
        adapter = push_task.run_adapter(run, enc.load(None))
    elif data_parallel == 1:  # commits before run_adapter: the one-device run's adapter
        adapter = push_task.make_push_adapter(run.env, enc.load(None), expert_config=run.expert)
    else:
        raise SystemExit("--data-parallel needs a commit with train.push_task.run_adapter")
    runner = Runner(make_train(run.train, adapter))
    ts = runner.init(jax.random.PRNGKey(0))
    rows = []
    for _ in range(batches):
        t0 = time.perf_counter()
        ts, m = runner.iteration(ts)
        rows.append(
            {
                "env_steps": int(ts.env_steps),
                "rollout_s": float(m["rollout_s"]),
                "learn_s": float(m["learn_s"]),
                "wall_s": time.perf_counter() - t0,
                "learning": bool(m["learning"]),
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    package = Path(mjx_push.__file__).parent
    commit = subprocess.run(
        ["git", "describe", "--always", "--dirty"], cwd=package, capture_output=True, text=True
    ).stdout.strip()
    return {
        "agent": agent,
        "preset": preset,
        "data_parallel": data_parallel,
        "package": str(package),
        "commit": commit,
        "batches": rows,
    }


def summary(label: str, result: dict) -> dict:
    learning = [b for b in result["batches"][1:] if b["learning"]]
    if not learning:
        raise SystemExit(f"{label}: no batch after the first learned; ask for more --batches")

    def med(key):
        return statistics.median(b[key] for b in learning)

    return {
        "label": label,
        "first_batch_s": result["batches"][0]["wall_s"],
        "batch_s": med("wall_s"),
        "rollout_s": med("rollout_s"),
        "learn_s": med("learn_s"),
        "learning_batches": len(learning),
    }


def at_commit(commit: str, args: argparse.Namespace, out: Path) -> dict:
    """This measurement run by `commit`'s code, in its worktree, with its own interpreter."""
    from benchmarks.protocol_at_commit import environment, worktree

    root = out.parent / "worktrees"
    root.mkdir(parents=True, exist_ok=True)
    tree = worktree(commit, root)
    python = environment(commit, root, tree)
    child_out = root / f"batch_speed-{commit}.json"
    cmd = [str(python), str(Path(__file__).resolve()), "--agent", args.agent, "--preset", args.preset]
    cmd += ["--batches", str(args.batches), "--data-parallel", str(args.data_parallel), "--child", str(child_out)]
    subprocess.run(cmd, cwd=tree, check=True, env={**os.environ, "MJX_PUSH_COMPILE_CACHE": "off"})
    return json.loads(child_out.read_text())


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--agent", default="egru")
    p.add_argument("--preset", default="cpu-long")
    p.add_argument("--batches", type=int, default=6, help="batches per row, the first (compilation) included")
    p.add_argument("--data-parallel", type=int, default=1, help="devices the run is split over (loop.data_parallel)")
    p.add_argument("--commits", nargs="+", default=["HEAD"], help="HEAD is this checkout; others run in worktrees")
    p.add_argument("--out", type=Path, default=Path("outputs/bench_batch_speed.json"))
    p.add_argument("--child", type=Path, help=argparse.SUPPRESS)  # one measurement, its JSON at this path
    a = p.parse_args(argv)
    if a.batches < 2:
        p.error(f"--batches must be at least 2 (the first compiles), got {a.batches}")
    if a.data_parallel < 1:
        p.error(f"--data-parallel must be at least 1, got {a.data_parallel}")
    if a.child is not None:
        a.child.write_text(json.dumps(measure(a.agent, a.preset, a.batches, a.data_parallel)))
        return

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # also when run as a file, not with -m
    from benchmarks.output import write_json

    rows, raw = [], {}
    for commit in a.commits:
        result = (
            measure(a.agent, a.preset, a.batches, a.data_parallel) if commit == "HEAD" else at_commit(commit, a, a.out)
        )
        raw[commit] = result
        rows.append(summary(commit, result))

    from rich.console import Console
    from rich.table import Table

    title = f"training batches: {a.agent} {a.preset}, {a.data_parallel} device(s), median over the batches that learn"
    table = Table(title=title)
    for col in ("code", "first batch s", "batch s", "rollout s", "updates s", "batches"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            r["label"],
            f"{r['first_batch_s']:.1f}",
            f"{r['batch_s']:.1f}",
            f"{r['rollout_s']:.1f}",
            f"{r['learn_s']:.1f}",
            str(r["learning_batches"]),
        )
    Console().print(table)
    write_json(a.out, {"rows": rows, "runs": raw, "cpus": os.cpu_count()})


if __name__ == "__main__":
    main()

"""brax's own trainers (PPO or SAC) on the pushing task through `mjx_push.brax_env.BraxPushEnv` and
brax's training wrappers, for a short budget: does the pipeline run, how fast, and what does it learn.

    python -m benchmarks.brax_train [--algo ppo] [--timesteps 20000] [--num-envs 16] [--observation latent]
                                    [--reward sparse] [--max-substeps N] [--out outputs/bench_brax_train.json]

The environment is the MJX scene with one object shape (cuboids), episodes of 50 steps ending as
truncations (PPO with bootstrap_on_timeout=True, SAC's truncation mask). brax evaluates --num-envs
episodes --evals times; its "episode_success" sums the steps spent within 1 cm of the goal and
"episode_distance" the object-goal distance over the 50 steps (the table divides it by 50).
`--max-substeps` caps a step's substeps (the a_s range's upper end) to make steps cheaper on CPU.
Prints a table (env steps, wall time, evaluation reward, steps at the goal, mean distance) and the
throughput, and writes JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
from rich.console import Console
from rich.table import Table

from mjx_push.brax_env import OBSERVATIONS, REWARDS, BraxPushEnv
from mjx_push.env import EnvConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", choices=("ppo", "sac"), default="ppo")
    ap.add_argument("--timesteps", type=int, default=20_000)
    ap.add_argument("--num-envs", type=int, default=16)
    ap.add_argument("--evals", type=int, default=4)
    ap.add_argument("--observation", choices=OBSERVATIONS, default="latent")
    ap.add_argument("--reward", choices=REWARDS, default="sparse")
    ap.add_argument("--max-substeps", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_brax_train.json"))
    args = ap.parse_args()
    console = Console()

    config = EnvConfig()
    if args.max_substeps is not None:
        config = dataclasses.replace(config, substeps=(config.substeps[0], args.max_substeps))
    env = BraxPushEnv(config, "box", observation=args.observation, reward=args.reward)
    L = env.episode_length
    # What both trainers share: the budget, the episode, the batch of environments, the evaluations.
    common = dict(
        num_timesteps=args.timesteps,
        episode_length=L,
        num_envs=args.num_envs,
        num_eval_envs=args.num_envs,
        num_evals=args.evals,
        discounting=0.95,
        normalize_observations=True,
        seed=args.seed,
    )
    if args.algo == "ppo":
        from brax.training.agents.ppo import train as ppo

        train_fn = functools.partial(
            ppo.train,
            **common,
            unroll_length=10,
            batch_size=args.num_envs,
            num_minibatches=4,
            num_updates_per_batch=4,
            learning_rate=3e-4,
            entropy_cost=1e-3,
            bootstrap_on_timeout=True,
        )
    else:
        from brax.training.agents.sac import train as sac

        train_fn = functools.partial(
            sac.train,
            **common,
            learning_rate=1e-3,
            tau=0.05,
            batch_size=256,
            min_replay_size=min(2_000, args.timesteps // 2),
            max_replay_size=args.timesteps,
            grad_updates_per_step=1,
        )

    rows, t0 = [], time.perf_counter()

    def progress(steps, metrics):
        row = {
            "env_steps": int(steps),
            "wall_s": time.perf_counter() - t0,
            "eval_reward": float(metrics.get("eval/episode_reward", float("nan"))),
            "eval_steps_at_goal": float(metrics.get("eval/episode_success", float("nan"))),
            "eval_mean_distance": float(metrics.get("eval/episode_distance", float("nan"))) / L,
        }
        rows.append(row)
        console.print(
            f"  {row['env_steps']:>8,} env steps  {row['wall_s']:6.0f} s  eval reward "
            f"{row['eval_reward']:.2f}, steps at goal {row['eval_steps_at_goal']:.2f}, "
            f"mean distance {100 * row['eval_mean_distance']:.1f} cm"
        )

    console.print(
        f"[bold]brax {args.algo}[/] on BraxPushEnv ({args.observation} observations, {args.reward} "
        f"reward, substeps {config.substeps}): {args.timesteps:,} env steps, {args.num_envs} envs; "
        f"backend {jax.default_backend()} (the first evaluation includes compilation)"
    )
    _, _, _ = train_fn(environment=env, progress_fn=progress)
    wall = time.perf_counter() - t0

    table = Table(title=f"brax {args.algo} on the pushing task ({args.num_envs} evaluation episodes each)")
    for col in ("env steps", "wall s", "eval reward", "steps at goal", "mean distance (cm)"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            f"{r['env_steps']:,}",
            f"{r['wall_s']:.0f}",
            f"{r['eval_reward']:.2f}",
            f"{r['eval_steps_at_goal']:.2f}",
            f"{100 * r['eval_mean_distance']:.1f}",
        )
    console.print(table)
    # Throughput after compilation: between the first and the last evaluation.
    sps = None
    if len(rows) >= 2 and rows[-1]["env_steps"] > rows[0]["env_steps"]:
        sps = (rows[-1]["env_steps"] - rows[0]["env_steps"]) / (rows[-1]["wall_s"] - rows[0]["wall_s"])
        console.print(f"throughput after the first evaluation: {sps:,.0f} env steps/s (evaluations included)")
    console.print(f"wall time {wall:.0f} s in all")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
                "substeps": list(config.substeps),
                "curve": rows,
                "wall_s": wall,
                "env_steps_per_s": sps,
                "backend": jax.default_backend(),
            },
            indent=2,
        )
        + "\n"
    )
    console.print(f"written {args.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()

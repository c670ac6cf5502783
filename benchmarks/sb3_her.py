"""Stable-Baselines3 SAC + HER on the Gymnasium environment "MjxPush-v0", for a fixed budget of
environment steps, beside mjx-push's JAX learner on the same task.

    python -m benchmarks.sb3_her [--steps 3000] [--eval-every 1000] [--eval-episodes 10]
                                 [--learning-starts 500] [--jax-run RUN_DIR] [--out outputs/bench_sb3_her.json]

SB3 runs its SAC with `HerReplayBuffer` at SB3's default HER settings (future strategy, 4 sampled goals,
no info copied: the rewards of relabelled goals are right because the environment's reward is a
function of the goals alone) and the reference's SAC settings (learning rate 1e-3, batch 256, tau 0.05,
gamma 0.95, MLP [128, 256, 64] for actor and critics), one gradient step per environment step after
--learning-starts random steps. The environment is CPU MuJoCo with analytic masks (the ones MJX trains
with) and the encoder latent observation. With --jax-run, the task (EnvConfig) is that run's, and the
evaluations in its metrics.csv (`mjx-push train`) are printed beside SB3's, by environment steps.

Every --eval-every steps SB3's policy plays --eval-episodes deterministic episodes (seeds 10_000 + k)
and the success rate, mean episode reward and mean final object-goal distance are recorded. Prints the
learning curves as a table and writes JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax) and EGL
import numpy as np
from rich.console import Console
from rich.table import Table

import mjx_push.export  # noqa: F401  (registers MjxPush-v0)
from mjx_push.export.gym_env import MjxPushGymEnv
from mjx_push.env import EnvConfig


def evaluate(model, env: MjxPushGymEnv, episodes: int) -> dict:
    success, reward, final = [], [], []
    for k in range(episodes):
        obs, info = env.reset(seed=10_000 + k)
        total, done = 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, r, terminated, truncated, info = env.step(action)
            total += r
            done = terminated or truncated
        success.append(float(info["is_success"]))
        reward.append(total)
        final.append(float(info["distance"]))
    return {
        "success_rate": float(np.mean(success)),
        "mean_reward": float(np.mean(reward)),
        "final_distance": float(np.mean(final)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=3000, help="SB3 environment steps")
    ap.add_argument("--eval-every", type=int, default=1000)
    ap.add_argument("--eval-episodes", type=int, default=10)
    ap.add_argument("--learning-starts", type=int, default=500, help="random-action steps before learning")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jax-run", type=Path, default=None, help="an mjx-push train run directory to compare with")
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_sb3_her.json"))
    args = ap.parse_args()
    try:
        import torch
        from stable_baselines3 import SAC, HerReplayBuffer
    except ImportError:
        raise SystemExit("this benchmark needs Stable-Baselines3: pip install -e '.[sb3]'") from None
    torch.set_num_threads(1)
    console = Console()

    config, jax_curve = EnvConfig(), None
    if args.jax_run is not None:
        from mjx_push.train.comparison.report import read_training
        from mjx_push.train.presets import load_config

        config = load_config(args.jax_run / "config.json").env  # the same task as the JAX run
        jax_curve = read_training(args.jax_run)
    env = MjxPushGymEnv(config, mask_source="analytic")
    eval_env = MjxPushGymEnv(config, mask_source="analytic")
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        learning_rate=1e-3,
        buffer_size=max(args.steps, 10_000),
        batch_size=256,
        tau=0.05,
        gamma=0.95,
        learning_starts=args.learning_starts,
        policy_kwargs={"net_arch": [128, 256, 64]},
        seed=args.seed,
        verbose=0,
    )
    curve = [{"env_steps": 0, **evaluate(model, eval_env, args.eval_episodes), "wall_s": 0.0}]
    t0 = time.perf_counter()
    train_s = 0.0
    while curve[-1]["env_steps"] < args.steps:
        n = min(args.eval_every, args.steps - curve[-1]["env_steps"])
        t = time.perf_counter()
        model.learn(total_timesteps=n, reset_num_timesteps=False)
        train_s += time.perf_counter() - t
        row = {
            "env_steps": model.num_timesteps,
            **evaluate(model, eval_env, args.eval_episodes),
            "wall_s": time.perf_counter() - t0,
        }
        curve.append(row)
        console.print(
            f"  SB3 {row['env_steps']:>6} env steps: success {row['success_rate']:.0%}, "
            f"reward {row['mean_reward']:.1f}, final distance {100 * row['final_distance']:.1f} cm"
        )

    table = Table(title=f"SB3 SAC + HER on MjxPush-v0 (CPU MuJoCo, {args.eval_episodes} evaluation episodes)")
    for col in ("env steps", "success", "mean reward", "final dist (cm)", "wall s"):
        table.add_column(col, justify="right")
    for r in curve:
        table.add_row(
            f"{r['env_steps']:,}",
            f"{r['success_rate']:.0%}",
            f"{r['mean_reward']:.1f}",
            f"{100 * r['final_distance']:.1f}",
            f"{r['wall_s']:.0f}",
        )
    console.print(table)
    console.print(
        f"SB3 training: {model.num_timesteps:,} env steps in {train_s:.0f} s "
        f"({model.num_timesteps / train_s:.1f} env steps/s incl. updates)"
    )
    if jax_curve is not None:
        jt = Table(title=f"mjx-push JAX learner, {args.jax_run} ({jax_curve['env_steps']:,} env steps)")
        for col in ("env steps", "success", "mean reward", "final dist (cm)"):
            jt.add_column(col, justify="right")
        for steps, success, reward, dist in zip(
            jax_curve["eval_env_steps"],
            jax_curve["eval_success"],
            jax_curve["eval_reward"],
            jax_curve["eval_final_distance"],
        ):
            jt.add_row(f"{steps:,}", f"{success:.0%}", f"{reward:.1f}", f"{100 * dist:.1f}")
        console.print(jt)
        console.print(
            f"JAX training: {jax_curve['env_steps']:,} env steps, {jax_curve['updates']:,} updates in "
            f"{jax_curve['wall_s']:.0f} s"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
                "env_config": dataclasses.asdict(config),
                "sb3": {"curve": curve, "train_s": train_s, "env_steps": model.num_timesteps},
                "jax": jax_curve,
            },
            indent=2,
            default=str,
        )
        + "\n"
    )
    console.print(f"written {args.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()

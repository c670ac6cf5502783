"""The same exported policy in both simulators: MJX (`mjx-push eval`) and CPU MuJoCo (`mjx-push deploy`).

    python -m benchmarks.sim_parity POLICY.npz [--episodes 100] [--setting standard] [--shape all]
                                    [--out outputs/bench_sim_parity.json]

Both run the same episodes: the objects, starts and goals of the evaluation protocol
(`train.evaluate`, fixed seeds) are handed to the CPU environment as well. In MJX the policy acts
through JAX (the .npz loaded back into network params); on CPU through `export.numpy_policy` with
analytic masks. Prints both metric tables side by side, the fraction of episodes whose success agrees,
and the final-distance differences; writes JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import numpy as np
from rich.console import Console
from rich.table import Table

from export.cpu_env import CpuPushEnv
from export.numpy_policy import NumpyPolicy
from export.policy_file import load_as_policy
from train.evaluate import METRICS, EvalSpec, evaluator_for, summarize


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policy", type=Path)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--setting", default="standard")
    ap.add_argument("--shape", default="all")
    ap.add_argument("--batch", type=int, default=20)
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_sim_parity.json"))
    args = ap.parse_args()
    console = Console()

    policy = load_as_policy(args.policy)
    spec = EvalSpec(
        setting=args.setting, shape=args.shape, episodes=args.episodes, batch=min(args.batch, args.episodes)
    )
    ev = evaluator_for(policy.config.env, policy.config.train.agent, spec.batch)
    t0 = time.perf_counter()
    mjx = ev.evaluate(policy, spec)["per_episode"]
    t_mjx = time.perf_counter() - t0

    numpy_policy = NumpyPolicy.from_file(args.policy)
    env = CpuPushEnv(policy.config.env, mask_source="analytic")
    cpu: dict[str, list] = {k: [] for k in (*METRICS, "final_distance")}
    t0 = time.perf_counter()
    for i in range(spec.episodes):
        geom = (
            ("box", "cylinder")[i % 2] if spec.shape == "all" else ("cylinder" if spec.shape == "cylinder" else "box")
        )
        params, _ = ev.episode_params(spec, geom, np.array([i]))
        params = type(params)(**{k: np.asarray(getattr(params, k))[0] for k in params.__dataclass_fields__})
        obs = env.reset(seed=spec.seed + i, params=params, geom_type=geom)
        numpy_policy.reset()
        reward = 0.0
        for _ in range(policy.config.env.episode_length):
            obs, r, _, _, info = env.step(numpy_policy.act_raw(obs["object_mask"], obs["goal_mask"], obs["ee_xy"]))
            reward += r
        valid = not info["episode_invalid"]
        cpu["success"].append(float(valid and info["success"]))
        cpu["reward"].append(reward if valid else -float(policy.config.env.episode_length))
        cpu["overshoot"].append(float(info["corrections"].overshoot))
        cpu["distance"].append(float(info["corrections"].distance))
        cpu["final_distance"].append(float(info["distance"]))
    t_cpu = time.perf_counter() - t0

    s_mjx, s_cpu = summarize(mjx), summarize(cpu)
    table = Table(title=f"{policy.config.agent}: {spec.episodes} episodes, {spec.setting}, {spec.shape}")
    for col in ("metric", "MJX (JAX policy)", "CPU MuJoCo (NumPy policy)"):
        table.add_column(col, justify="right")
    for m in METRICS:
        table.add_row(
            m, f"{s_mjx[m]['mean']:.3f} ± {s_mjx[m]['sem']:.3f}", f"{s_cpu[m]['mean']:.3f} ± {s_cpu[m]['sem']:.3f}"
        )
    agree = float(np.mean(np.asarray(mjx["success"]) == np.asarray(cpu["success"])))
    dd = np.abs(np.asarray(mjx["final_distance"]) - np.asarray(cpu["final_distance"]))
    table.add_row("success agreement", f"{agree:.2f}", "")
    table.add_row("|final distance diff| median / max (m)", f"{np.median(dd):.4f} / {dd.max():.4f}", "")
    table.add_row("wall s (incl. compile)", f"{t_mjx:.0f}", f"{t_cpu:.0f}")
    console.print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "policy": str(args.policy),
                "spec": vars(args) | {"policy": str(args.policy), "out": str(args.out)},
                "mjx": s_mjx,
                "cpu": s_cpu,
                "success_agreement": agree,
                "final_distance_diff_median": float(np.median(dd)),
                "final_distance_diff_max": float(dd.max()),
                "wall_s": {"mjx": t_mjx, "cpu": t_cpu},
            },
            indent=2,
        )
        + "\n"
    )
    console.print(f"written {args.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()

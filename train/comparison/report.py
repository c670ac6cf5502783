"""Markdown report and figures of the paper's comparison (VPM, Stacked, uGRU, eGRU) per shape.

`results[agent][shape]` is a list with one evaluation summary per training seed (as returned by
`mjx_push.train.evaluate.summarize`: {metric: {"mean", "sem", "n"}}). With one seed the error bars are the
standard error over test episodes; with several, the standard error across the seeds' means.
"""

from __future__ import annotations

import csv
import functools
import json
from pathlib import Path

import numpy as np

from mjx_push.train import presets
from mjx_push.train.evaluate import DISTANCE_METRICS, METRICS, sem
from mjx_push.train.loop import improves
from mjx_push.errors import ConfigError

LABELS = {
    "success": "success rate",
    "reward": "mean episode reward",
    "overshoot": "overshoot corrections",
    "distance": "distance corrections",
}
AGENT_NAMES = {
    "vpm": "VPM",
    "stacked": "Stacked",
    "ugru": "uGRU",
    "egru": "eGRU",
    "expert": "scripted expert (ground truth)",
}
SHAPE_NAMES = {
    "cylinder": "cylinder",
    "square": "square cuboid",
    "rectangular": "rectangular cuboid",
    "all": "all shapes",
    "cuboid": "cuboid",
}


def combine(summaries: list[dict]) -> dict:
    """One {metric: {"mean", "sem", "n_seeds", "n_episodes"}} from the per-seed summaries (the paper's
    metrics, and the distances when every seed has them)."""
    out = {}
    for m in METRICS + tuple(k for k in DISTANCE_METRICS if all(k in s for s in summaries)):
        means = np.array([s[m]["mean"] for s in summaries])
        err = summaries[0][m]["sem"] if len(summaries) == 1 else sem(means)
        out[m] = {
            "mean": float(means.mean()),
            "sem": float(err),
            "n_seeds": len(summaries),
            "n_episodes": int(sum(s[m]["n"] for s in summaries)),
        }
    return out


def table(results: dict) -> str:
    """Markdown table: one row per (shape, agent)."""
    lines = [
        "| shape | agent | success rate | mean reward | overshoot corr. | distance corr. | "
        "object-goal distance, reset -> end (cm) |",
        "|---|---|---|---|---|---|---|",
    ]
    shapes = list(next(iter(results.values())).keys())
    for shape in shapes:
        for agent in results:
            c = combine(results[agent][shape])
            s = c["success"]
            cells = [f"{100 * s['mean']:.0f} ± {100 * s['sem']:.0f} %"]
            cells += [f"{c[m]['mean']:.2f} ± {c[m]['sem']:.2f}" for m in ("reward", "overshoot", "distance")]
            if "final_distance" in c:
                cells.append(
                    f"{100 * c['start_distance']['mean']:.1f} -> {100 * c['final_distance']['mean']:.1f} "
                    f"± {100 * c['final_distance']['sem']:.1f}"
                )
            else:
                cells.append("-")
            lines.append(
                f"| {SHAPE_NAMES.get(shape, shape)} | {AGENT_NAMES.get(agent, agent)} | " + " | ".join(cells) + " |"
            )
    return "\n".join(lines)


def bar_figure(results: dict, path: Path) -> None:
    """2x2 bar charts (success, reward, overshoot, distance) of agents per shape, with SEM error bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    agents = list(results)
    shapes = list(results[agents[0]])
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    width = 0.8 / len(agents)
    for ax, m in zip(axes.flat, METRICS):
        for j, agent in enumerate(agents):
            stats = [combine(results[agent][s])[m] for s in shapes]
            scale = 100.0 if m == "success" else 1.0
            ax.bar(
                np.arange(len(shapes)) + (j - (len(agents) - 1) / 2) * width,
                [scale * s["mean"] for s in stats],
                width,
                yerr=[scale * s["sem"] for s in stats],
                capsize=3,
                label=AGENT_NAMES.get(agent, agent),
            )
        ax.set_xticks(np.arange(len(shapes)), [SHAPE_NAMES.get(s, s) for s in shapes], fontsize=8)
        ax.set_title(LABELS[m] + (" (%)" if m == "success" else ""))
        ax.grid(axis="y", alpha=0.3)
    axes.flat[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def friction_force_samples(n: int = 200_000, seed: int = 0) -> dict[str, np.ndarray]:
    """Sliding friction force F = m * mu * g of the two samplers (uniform; improved), drawn with the
    project's own samplers under Table I's ranges. The same for every report of a process, so drawn
    once per (n, seed): tracing the vmapped sampler costs more than a small report's evaluations."""
    return dict(_friction_force_samples(n, seed))


@functools.lru_cache(maxsize=4)
def _friction_force_samples(n: int, seed: int) -> dict[str, np.ndarray]:
    import jax

    from mjx_push import objects, scene

    home = scene.home_flange_pos()[:2]
    out = {}
    for mode in ("uniform", "improved"):
        cfg = objects.ObjectConfig(mode=mode, shape="cylinder")
        keys = jax.random.split(jax.random.PRNGKey(seed), n)
        p = jax.jit(jax.vmap(lambda k: objects.sample(k, cfg, "cylinder", home)))(keys)
        out[mode] = np.asarray(p.mass * p.friction[:, 0] * 9.81)
        out[mode].setflags(write=False)  # shared by every later call
    return out


def friction_figure(path: Path, samples: dict[str, np.ndarray] | None = None) -> None:
    """Densities of the sliding friction force under both samplers (the paper's Fig. 4)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = samples or friction_force_samples()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5), sharey=False)
    hi = max(float(v.max()) for v in samples.values())
    bins = np.linspace(0.0, hi, 80)
    for ax, (mode, f) in zip(axes, samples.items()):
        ax.hist(f, bins=bins, density=True, color="tab:blue" if mode == "uniform" else "tab:orange")
        ax.set_title(f"{mode} sampling")
        ax.set_xlabel("sliding friction force m * mu * g (N)")
        ax.set_ylabel("density")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def read_training(run_dir: Path) -> dict:
    """A run's training record from its metrics.csv: the evaluations during training (env steps, mean
    reward, success rate, final distance), the env step of the actor the selection rule keeps, and its
    cost (env steps, updates, wall time summed over iterations, so time lost to an interruption is not
    counted but each resume's compilation is)."""
    path = Path(run_dir) / "metrics.csv"
    if not path.is_file():
        raise ConfigError(f"no metrics.csv in {run_dir}: not a training run directory")
    with path.open() as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ConfigError(f"{path} has no rows")
    evals = [r for r in rows if r.get("eval/mean_reward")]
    steps = [int(r["env_steps"]) for r in evals]
    reward = [float(r["eval/mean_reward"]) for r in evals]
    success = [float(r["eval/success_rate"]) for r in evals]
    selected, best_r, best_s = None, -float("inf"), 0.0
    for step, r, s in zip(steps, reward, success):  # the training's own selection, replayed
        if improves(r, s, best_r, best_s):
            selected, best_r, best_s = step, r, s
    return {
        "eval_env_steps": steps,
        "eval_reward": reward,
        "eval_success": success,
        # Runs logged before the distances were: NaN (the figure leaves them out).
        "eval_final_distance": [float(r.get("eval/final_distance") or "nan") for r in evals],
        "selected_env_steps": selected,
        "env_steps": int(rows[-1]["env_steps"]),
        "updates": int(rows[-1]["updates"]),
        "wall_s": float(sum(float(r["iteration_s"]) for r in rows)),
    }


def curve_figure(training: dict[str, list[dict]], path: Path) -> None:
    """Mean evaluation reward, success rate and final object-goal distance during training vs env steps,
    one line per seed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 3.5))
    for j, (agent, runs) in enumerate(training.items()):
        for k, t in enumerate(runs):
            label = AGENT_NAMES.get(agent, agent) if k == 0 else None
            axes[0].plot(t["eval_env_steps"], t["eval_reward"], "o-", color=f"C{j}", label=label, alpha=0.8)
            axes[1].plot(
                t["eval_env_steps"], [100 * v for v in t["eval_success"]], "o-", color=f"C{j}", label=label, alpha=0.8
            )
            axes[2].plot(
                t["eval_env_steps"],
                [100 * v for v in t["eval_final_distance"]],
                "o-",
                color=f"C{j}",
                label=label,
                alpha=0.8,
            )
    for ax, title in zip(
        axes, ("mean evaluation reward", "evaluation success rate (%)", "object-goal distance at the end (cm)")
    ):
        ax.set_title(title)
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def training_table(training: dict[str, list[dict]]) -> str:
    lines = [
        "| agent | seeds | env steps | gradient updates | training wall time (min, mean per seed) | "
        "best evaluation reward (mean) | evaluated actor (env steps) |",
        "|---|---|---|---|---|---|---|",
    ]
    for agent, runs in training.items():
        best = np.mean([max(t["eval_reward"]) if t["eval_reward"] else np.nan for t in runs])
        picked = ", ".join(f"{t['selected_env_steps']:,}" if t["selected_env_steps"] is not None else "-" for t in runs)
        lines.append(
            f"| {AGENT_NAMES.get(agent, agent)} | {len(runs)} | {runs[0]['env_steps']:,} | "
            f"{runs[0]['updates']:,} | {np.mean([t['wall_s'] for t in runs]) / 60:.1f} | {best:.2f} | "
            f"{picked} |"
        )
    return "\n".join(lines)


def write_report(out_dir: Path, results: dict, meta: dict, runs: dict[str, list[Path]] | None = None) -> Path:
    """report.md, results.json, metrics.png, friction_force.png in `out_dir`; with the training `runs`
    ({agent: [run dir per seed]}) also learning_curves.png and a training-cost table."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    bar_figure(results, out_dir / "metrics.png")
    friction_figure(out_dir / "friction_force.png")
    training = {a: [read_training(d) for d in dirs] for a, dirs in (runs or {}).items()}
    training_text = ""
    if training:
        curve_figure(training, out_dir / "learning_curves.png")
        training_text = f"""
## Training

Deterministic evaluations during training ({meta.get("budget")} budget; the best policy by mean reward
is the one evaluated above):

![learning curves](learning_curves.png)

{training_table(training)}
"""
    combined = {a: {s: combine(v) for s, v in per_shape.items()} for a, per_shape in results.items()}
    (out_dir / "results.json").write_text(
        json.dumps({"meta": meta, "per_seed": results, "combined": combined, "training": training}, indent=2) + "\n"
    )
    missing = meta.get("missing_runs") or []
    missing_text = (
        f"\nNot finished when this report was built, so not in it: {', '.join(missing)}.\n" if missing else ""
    )
    seeds = meta.get("seeds", 1)
    err = "standard error across seeds" if seeds > 1 else "standard error over test episodes"
    total_flag = f" --total-env-steps {meta['total_env_steps']}" if meta.get("budget_total_changed") else ""
    budget_name = meta.get("budget", "?") + (f" ({meta['total_env_steps']:,} env steps)" if total_flag else "")
    total_flag += presets.set_flag(meta.get("overrides"))
    title = f"{budget_name} budget"
    teacher_text = ""
    if meta.get("teacher_free"):
        total_flag += f" --teacher-free {meta['teacher_free']}"
        title += ", then without the teacher"
        start, end, total = meta["teacher_free_env_steps"]
        teacher_text = f"""
Each agent trained with its teacher to {start:,} env steps, then forked there and trained on to
{total:,}: the cloning weight and the expert's share of environments fell from 1 to 0 between
{start:,} and {end:,} env steps (the actor held to its copy at the fork), and the last {total - end:,}
were the agent's own. The table scores each fork's kept actor.
"""
    text = f"""# mjx-push reproduction: {title}

Agents trained with `mjx-push reproduce --budget {meta.get("budget")} --seeds {seeds}{total_flag}`, each evaluated on
{meta.get("episodes")} deterministic episodes per shape in the **{meta.get("setting")}** setting
(the same seeds for every agent). Values are mean ± {err}.
{teacher_text}
{table(results)}
{missing_text}
![metrics per shape and agent](metrics.png)

Sliding friction force densities of the two samplers (paper Fig. 4), drawn from `mjx_push.objects`:

![friction force densities](friction_force.png)
{training_text}
Wall time of this `reproduce` invocation: {meta.get("wall_s", 0) / 60:.1f} min ({meta.get("machine", "")}); runs and
evaluations it reused from an earlier invocation are not counted (the training table has each run's own time).
"""
    path = out_dir / "report.md"
    path.write_text(text)
    return path

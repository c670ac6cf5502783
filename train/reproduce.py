"""`mjx-push reproduce`: train the paper's four agents, evaluate each on the difficult case per shape,
and write the report (train/report.py).

Runs live in `<out>/runs/<agent>-s<seed>`; a finished run (summary.json present) is reused and an
interrupted one resumed from its checkpoint, so rerunning the command after a crash redoes nothing.
"""

from __future__ import annotations

import dataclasses
import json
import platform
import time
from pathlib import Path
from typing import Callable

from train import presets
from train import run as run_mod
from train.evaluate import EvalSpec, Evaluator, evaluator_for
from train.report import write_report

AGENTS = ("vpm", "stacked", "ugru", "egru")
PAPER_SHAPES = ("cylinder", "square", "rectangular")
EVAL_EPISODES = {"smoke": 8, "paper": 100, "gpu": 100}


def shared_evaluator(cfg: presets.RunConfig, batch: int) -> Evaluator:
    """Evaluations draw their own objects (uniformly), and uGRU and eGRU share one network, so the
    evaluator is keyed by what changes its compiled code only."""
    env = dataclasses.replace(cfg.env, objects=dataclasses.replace(cfg.env.objects, mode="uniform"))
    agent = cfg.train.agent
    if agent.kind == "egru":
        agent = dataclasses.replace(agent, kind="ugru")
    return evaluator_for(env, agent, batch)


def train_or_reuse(cfg: presets.RunConfig, run_dir: Path, log: Callable[[str], None]) -> None:
    if (run_dir / "summary.json").is_file() and (run_dir / "best_policy.msgpack").is_file():
        saved = run_mod.load_config(run_dir / "config.json")
        if saved != cfg:
            raise ValueError(f"{run_dir} holds a finished run of another configuration; use another --out")
        log(f"reusing finished run {run_dir}")
        return
    resume = (run_dir / "checkpoints").is_dir() and any((run_dir / "checkpoints").iterdir())
    log(("resuming " if resume else "training ") + str(run_dir))
    run_mod.run(cfg, run_dir, resume=resume)


def reproduce(
    budget: str,
    seeds: int,
    out: Path,
    episodes: int | None = None,
    agents: tuple[str, ...] = AGENTS,
    shapes: tuple[str, ...] = PAPER_SHAPES,
    setting: str = "difficult",
    log: Callable[[str], None] = print,
    config_hook: Callable[[presets.RunConfig], presets.RunConfig] | None = None,
) -> Path:
    """Train + evaluate every agent for `seeds` seeds; returns the report's path. `config_hook` lets
    tests shrink the runs."""
    if seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {seeds}")
    for a in agents:
        if a not in AGENTS:
            raise ValueError(f"agents must be among {AGENTS}, got {a!r}")
    out = Path(out)
    episodes = episodes or EVAL_EPISODES[budget]
    t0 = time.perf_counter()
    results: dict[str, dict[str, list]] = {a: {s: [] for s in shapes} for a in agents}
    for seed in range(seeds):
        for agent in agents:
            cfg = presets.make(agent, budget, seed)
            cfg = config_hook(cfg) if config_hook else cfg
            run_dir = out / "runs" / f"{agent}-s{seed}"
            train_or_reuse(cfg, run_dir, log)
            policy = run_mod.load_policy(run_dir / "best_policy")
            batch = min(episodes, 20)
            # The evaluation samples its own objects, so uGRU and eGRU (which differ only in the training
            # sampler) share one compiled evaluator.
            ev = shared_evaluator(cfg, batch)
            for shape in shapes:
                spec = EvalSpec(setting=setting, shape=shape, episodes=episodes, batch=batch)
                res = ev.evaluate(policy, spec)
                results[agent][shape].append(res["summary"])
                s = res["summary"]
                log(f"{agent} seed {seed} {shape}: success {s['success']['mean']:.2f}, "
                    f"reward {s['reward']['mean']:.1f}, overshoot {s['overshoot']['mean']:.2f}, "
                    f"distance {s['distance']['mean']:.2f}")
    meta = {"budget": budget, "seeds": seeds, "episodes": episodes, "setting": setting, "agents": list(agents),
            "shapes": list(shapes), "wall_s": time.perf_counter() - t0,
            "machine": f"{platform.machine()}, {__import__('os').cpu_count()} CPU cores, "
                       f"jax backend {__import__('jax').default_backend()}"}
    path = write_report(out, results, meta)
    (out / "reproduce.json").write_text(json.dumps(meta, indent=2) + "\n")
    return path

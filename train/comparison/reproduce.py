"""`mjx-push reproduce`: train the paper's four agents, evaluate each on the difficult case per shape,
and write the report (train/comparison/report.py).

Runs live in `<out>/runs/<agent>-s<seed>`; a finished run (summary.json present) is reused, an
interrupted one resumed from its checkpoint, and each finished evaluation is cached next to the run
(`eval-<setting>-<shape>-<episodes>.json`, tied to the policy's sha256: cache.py), so rerunning the
command after a crash redoes nothing. `jobs > 1` trains and evaluates that many agents (and the scripted
expert) at once in worker processes (jobs.py). The comparison's settings are one value, a `Study`
(study.py), which every function here takes and each job carries to its worker.

Across machines: `plan` lists one command per job (an agent and seed trained and evaluated, or the
expert's row) and the report's command, for any scheduler to run wherever `OUT` is shared;
`reproduce(..., report_only=True)` builds the report from the runs that have finished (evaluating any
not yet evaluated) and lists the others as missing.

Without the teacher (`teacher_free`): each finished run is forked at its end (train/runs/fork.py) into
`<out>/teacher-free/runs/<agent>-s<seed>` and trained further with the expert annealed away, and the
report in `<out>/teacher-free/` scores those forks. The budget's runs are the same ones a plain
reproduction of that `out` uses, so a comparison already run gains its teacher-free half without
retraining.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import shutil
import time
from pathlib import Path
from typing import Callable

import numpy as np

from mjx_push.errors import ConfigError
from mjx_push.train import configio, presets
from mjx_push.train.comparison.cache import eval_cache_path, evaluate_run, read_cache
from mjx_push.train.comparison.jobs import job_log, run_jobs
from mjx_push.train.comparison.report import write_report
from mjx_push.train.comparison.study import AGENTS, Study, budget_config
from mjx_push.train.evaluate import ExpertPolicy, evaluate, summarize
from mjx_push.train.runs import atomic
from mjx_push.train.runs import run as run_mod
from mjx_push.train.runs.checkpoints import saved_steps
from mjx_push.train.runs.fork import ForkSource


def train_or_reuse(
    cfg: presets.RunConfig, run_dir: Path, log: Callable[[str], None], fork: ForkSource | None = None
) -> None:
    """Reuse the finished run in `run_dir`, train it longer, resume it, or start it (from `fork`'s
    checkpoint when given)."""
    if (run_dir / "summary.json").is_file() and (run_dir / "best_policy.msgpack").is_file():
        saved = presets.load_config(run_dir / "config.json")
        if saved == cfg:
            log(f"reusing finished run {run_dir}")
            return
        if not configio.trained_longer(presets.config_dict(saved), presets.config_dict(cfg)):
            raise ConfigError(f"{run_dir} holds a finished run of another configuration; use another --out")
        log(f"training {run_dir} longer: {cfg.train.loop.total_env_steps:,} env steps in all")
        run_mod.run(cfg, run_dir, resume=True)  # never the restart below: a finished run is not discarded
        return
    resume = bool(saved_steps(run_dir / "checkpoints"))
    if not resume and run_dir.exists():
        # Killed before its first checkpoint: nothing to resume, and its logs would make `run` refuse
        # the directory as "already holding a run". Start it again from scratch.
        log(f"{run_dir} was stopped before its first checkpoint: starting it again")
        shutil.rmtree(run_dir)
    if resume:
        log(f"resuming {run_dir}")
        run_mod.run(cfg, run_dir, resume=True)
    elif fork is not None:
        log(f"forking {fork.run_dir} at its last checkpoint into {run_dir}")
        run_mod.run(cfg, run_dir, resume=False, fork=fork)
    else:
        log(f"training {run_dir}")
        run_mod.run(cfg, run_dir, resume=False)


def is_finished(run_dir: Path, total_env_steps: int | None = None) -> bool:
    """The run has finished (with `total_env_steps`, trained for exactly that many env steps: a run of a
    smaller budget is not the one asked for)."""
    run_dir = Path(run_dir)
    if not ((run_dir / "summary.json").is_file() and (run_dir / "best_policy.msgpack").is_file()):
        return False
    return total_env_steps is None or (
        presets.load_config(run_dir / "config.json").train.loop.total_env_steps == total_env_steps
    )


def expert_job(study: Study, log: Callable[[str], None] = print) -> dict[str, dict]:
    """The scripted expert under the budget's action box (and `study.overrides`, the agents' `--set`),
    per shape: the baseline row of the report (it reads the simulator's ground truth, so it bounds what
    the task allows, not what a policy sees). Cached in OUT/expert/ like the agents' evaluations,
    keyed by the spec and the settings."""
    # Only the environment and the expert matter here: the training's length and the tests' hook don't.
    cfg = budget_config(study.budget, "vpm", 0, overrides=study.overrides)
    key = {"env": presets.config_dict(cfg)["env"], "expert": presets.config_dict(cfg)["expert"]}
    summaries = {}
    for shape in study.shapes:
        spec = study.spec(shape)
        path = eval_cache_path(study.out / "expert", spec)
        want = {"spec": json.loads(json.dumps(dataclasses.asdict(spec))), "settings": key}
        cached = read_cache(path)
        if {k: cached.get(k) for k in want} == want:
            log(f"reusing evaluation {path}")
            summaries[shape] = summarize({k: np.asarray(v) for k, v in cached["per_episode"].items()})
            continue
        res = evaluate(ExpertPolicy(cfg), spec)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic.write_text(
            path,
            json.dumps(
                {
                    **want,
                    "summary": res["summary"],
                    "per_episode": {k: np.asarray(v).tolist() for k, v in res["per_episode"].items()},
                }
            )
            + "\n",
        )
        summaries[shape] = res["summary"]
        log(f"expert {shape}: success {summaries[shape]['success']['mean']:.2f}")
    return summaries


def agent_job(
    study: Study, agent: str, seed: int, log: Callable[[str], None] = print, train: bool = True
) -> dict[str, dict]:
    """Train (or reuse / resume) one agent and seed, then evaluate it per shape: {shape: summary}.
    ``train`` False evaluates a finished run only. A finished run of fewer steps than
    `study.total_env_steps` is trained longer from its checkpoint; with `study.teacher_free` the finished
    run is forked and trained that many env steps more without the teacher, and the fork is evaluated.
    Module-level and picklable, so `--jobs` can run it in a worker process."""
    cfg = study.config(agent, seed)
    run_dir = study.run_dir(agent, seed)
    stages = [(cfg, run_dir, None)]
    if study.teacher_free:
        fork_cfg, fork_dir = study.job_config(agent, seed)
        stages.append((fork_cfg, fork_dir, ForkSource(run_dir)))
    for stage_cfg, stage_dir, fork in stages:
        total = stage_cfg.train.loop.total_env_steps
        if train:
            train_or_reuse(stage_cfg, stage_dir, log, fork)
        elif not is_finished(stage_dir, total):
            raise ConfigError(f"{stage_dir} has not finished training ({total:,} env steps)")
    cfg, run_dir, _ = stages[-1]  # the run the table scores: the fork, when there is one
    summaries = {}
    for shape in study.shapes:
        s = summaries[shape] = evaluate_run(cfg, run_dir, study.spec(shape), log)
        log(
            f"{agent} seed {seed} {shape}: success {s['success']['mean']:.2f}, "
            f"reward {s['reward']['mean']:.1f}, overshoot {s['overshoot']['mean']:.2f}, "
            f"distance {s['distance']['mean']:.2f}"
        )
    return summaries


def _job(kind: str, *args, **kwargs):
    """One call of the pool: an agent's training and evaluation, or the expert's evaluation (module-level
    and picklable, for worker processes; here rather than in jobs.py, which knows no comparison)."""
    return {"agent": agent_job, "expert": expert_job}[kind](*args, **kwargs)


def plan(study: Study) -> list[str]:
    """One shell command per job (each agent and seed: train, then evaluate; the expert's row), then the
    command that builds the report from them. The jobs are independent: run them anywhere that shares
    `study.out`, in any order, and the report last (or at any time, for the runs finished so far)."""
    ep = f" --episodes {study.episodes}" if study.episodes else ""
    ep += f" --total-env-steps {study.total_env_steps}" if study.total_env_steps else ""
    ep += f" --teacher-free {study.teacher_free}" if study.teacher_free else ""
    ep += presets.set_flag(study.overrides)
    base = f"mjx-push reproduce --budget {study.budget} --out {study.out}{ep}"
    jobs = [f"{base} --job {agent}:{seed}" for agent, seed in study.runs()]
    return jobs + [
        f"{base} --job expert",
        f"{base} --seeds {study.seeds} --agents {' '.join(study.agents)} --report-only",
    ]


def reproduce(
    study: Study,
    log: Callable[[str], None] = print,
    jobs: int = 1,
    expert: bool = True,
    report_only: bool = False,
) -> Path:
    """Train + evaluate every agent of `study` for its seeds (`jobs` of them at a time, in worker
    processes when > 1), and the scripted expert as a baseline row (``expert``); returns the report's
    path (`study.report_dir`: with `teacher_free`, OUT/teacher-free, scoring the forks without the
    teacher). ``report_only``: train nothing; the report holds the runs that have finished (evaluated
    here if not yet) and names the others."""
    t0 = time.perf_counter()
    items = study.runs()
    scored = {i: study.job_config(*i) for i in items}
    missing = []
    if report_only:
        missing = [i for i in items if not is_finished(scored[i][1], scored[i][0].train.loop.total_env_steps)]
        items = [i for i in items if i not in missing]
        for i in missing:
            log(f"{scored[i][1]} has not finished: left out of the report")
        if not items:
            raise ConfigError(
                f"no finished run in {study.report_dir / 'runs'} for agents {study.agents} and {study.seeds} seed(s)"
            )
    calls = [
        (("agent", study, agent, seed), {"log": job_log(log, jobs, f"[{agent} s{seed}] "), "train": not report_only})
        for agent, seed in items
    ]
    if expert:  # last: the first worker to finish an agent takes it, beside the last agents
        calls.append((("expert", study), {"log": job_log(log, jobs, "[expert] ")}))
    summaries = run_jobs(_job, calls, jobs)
    done = {a for a, _ in items}
    results: dict[str, dict[str, list]] = {a: {s: [] for s in study.shapes} for a in AGENTS if a in done}
    for (agent, _), per_shape in zip(items, summaries):
        for shape in study.shapes:
            results[agent][shape].append(per_shape[shape])
    if expert:
        results["expert"] = {s: [v] for s, v in summaries[-1].items()}
    fork = scored[items[0]][0].train  # with teacher_free, every fork's schedule (one budget)
    meta = {
        "budget": study.budget,
        "total_env_steps": study.budget_env_steps,
        "budget_total_changed": study.total_env_steps is not None,
        "overrides": study.overrides or {},
        "teacher_free": study.teacher_free,
        # (anneal start, anneal end, total) of the forks: the report's account of the schedule
        "teacher_free_env_steps": [fork.demo.anneal_start, fork.demo.anneal_end, fork.loop.total_env_steps]
        if study.teacher_free
        else None,
        "seeds": study.seeds,
        "jobs": jobs,
        "episodes": study.episodes_per_shape,
        "setting": study.setting,
        "agents": list(results),
        "missing_runs": [f"{a}-s{s}" for a, s in missing],
        "shapes": list(study.shapes),
        "wall_s": time.perf_counter() - t0,
        "machine": f"{platform.machine()}, {os.cpu_count()} CPU cores, "
        f"jax backend {__import__('jax').default_backend()}",
    }
    runs = {a: [scored[a2, s][1] for a2, s in items if a2 == a] for a in results if a in AGENTS}
    path = write_report(study.report_dir, results, meta, runs)
    (study.report_dir / "reproduce.json").write_text(json.dumps(meta, indent=2) + "\n")
    return path

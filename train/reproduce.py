"""`mjx-push reproduce`: train the paper's four agents, evaluate each on the difficult case per shape,
and write the report (train/report.py).

Runs live in `<out>/runs/<agent>-s<seed>`; a finished run (summary.json present) is reused, an
interrupted one resumed from its checkpoint, and each finished evaluation is cached next to the run
(`eval-<setting>-<shape>-<episodes>.json`, tied to the policy's sha256), so rerunning the command after
a crash redoes nothing. `jobs > 1` trains and evaluates that many agents (and the scripted expert) at
once in worker processes: each process splits its environments over every core, but compilation and the
learner's updates run on one core, so on a CPU two jobs overlap what one leaves idle.

Across machines: `plan` lists one command per job (an agent and seed trained and evaluated, or the
expert's row) and the report's command, for any scheduler to run wherever `OUT` is shared;
`reproduce(..., report_only=True)` builds the report from the runs that have finished (evaluating any
not yet evaluated) and lists the others as missing.

Without the teacher (`teacher_free`): each finished run is forked at its end (train/fork.py) into
`<out>/teacher-free/runs/<agent>-s<seed>` and trained further with the expert annealed away, and the
report in `<out>/teacher-free/` scores those forks. The budget's runs are the same ones a plain
reproduction of that `out` uses, so a comparison already run gains its teacher-free half without
retraining.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import hashlib
import json
import multiprocessing
import platform
import shutil
import time
from pathlib import Path
from typing import Callable

import numpy as np

from train import atomic, configio, presets
from train.config import AGENT_KINDS
from train import run as run_mod
from train.checkpoints import saved_steps
from train.fork import ForkSource
from train import policies
from train.evaluate import DISTANCE_METRICS, METRICS, EvalSpec, ExpertPolicy, evaluate, evaluator_for, summarize
from train.report import read_training, write_report
from mjx_push.errors import ConfigError

AGENTS = AGENT_KINDS
# The order agents start in by default: uGRU and eGRU evaluate with the same compiled programs (one
# network; evaluation draws its own objects), so with two jobs eGRU starts once uGRU is done and loads
# them from the compilation cache instead of compiling them beside it.
SCHEDULE = ("ugru", "vpm", "stacked", "egru")
PAPER_SHAPES = ("cylinder", "square", "rectangular")
EVAL_EPISODES = {"smoke": 8, "cpu": 100, "cpu-long": 100, "teacher-free": 100, "reference": 100, "paper": 100}
TEACHER_FREE = "teacher-free"  # <out>/teacher-free/: the forks without the teacher and their report


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


def scored_policy(run_dir: Path) -> tuple[str, int]:
    """The saved actor the table scores, and its env steps: the best by the current selection rule
    (`loop.improves`) replayed over the run's evaluations (`report.read_training`). A run trained under
    an older rule saved another best; when the current rule picks the final evaluation, `final_policy`
    holds that actor."""
    run_dir = Path(run_dir)
    pick = read_training(run_dir)["selected_env_steps"]
    if pick is None:
        raise ConfigError(f"{run_dir}/metrics.csv records no evaluation: the run has no best policy")
    for name, key in (("best_policy", "best_env_steps"), ("final_policy", "env_steps")):  # train/run.py's records
        meta = run_dir / f"{name}.json"
        if meta.is_file() and json.loads(meta.read_text())["scores"].get(key) == pick:
            return name, pick
    raise ConfigError(
        f"the selection rule picks the actor of env step {pick} in {run_dir}, but neither "
        "best_policy nor final_policy holds it (a run of an older rule): retrain it"
    )


def policy_fingerprint(path: Path) -> str:
    """sha256 of policy weights (`path`.msgpack): a cached evaluation belongs to exactly these weights."""
    return hashlib.sha256(Path(path).with_suffix(".msgpack").read_bytes()).hexdigest()


def eval_cache_path(folder: Path, spec: EvalSpec) -> Path:
    """Where an evaluation of `spec` is cached in a run's (or the expert's) folder."""
    return Path(folder) / f"eval-{spec.setting}-{spec.shape}-{spec.episodes}.json"


def evaluate_run(
    cfg: presets.RunConfig, run_dir: Path, spec: EvalSpec, log: Callable[[str], None], policy: str | None = None
) -> dict:
    """The summary of `spec` for the run's `policy` (default: the one the selection rule picks,
    `scored_policy`), cached in the run dir as JSON (with the policy's fingerprint and the spec), so an
    interrupted reproduction never repeats a finished evaluation."""
    path = eval_cache_path(run_dir, spec)
    if policy is None:
        name, step = scored_policy(run_dir)
    else:
        scores = json.loads((run_dir / f"{policy}.json").read_text())["scores"]
        name, step = policy, scores.get("env_steps", scores.get("best_env_steps"))
    fingerprint = policy_fingerprint(run_dir / name)
    spec_record = dataclasses.asdict(spec)
    if path.is_file():
        cached = read_cache(path)
        per = cached.get("per_episode", {})
        if (
            cached.get("policy_sha256") == fingerprint
            and cached.get("spec") == json.loads(json.dumps(spec_record))
            and all(k in per for k in METRICS + DISTANCE_METRICS)
        ):  # older caches lack the distances
            log(f"reusing evaluation {path}")
            return summarize({k: np.asarray(v) for k, v in per.items()})
    t0 = time.perf_counter()
    res = evaluator_for(cfg.env, cfg.train.agent, spec.batch).evaluate(policies.load_policy(run_dir / name), spec)
    record = {
        "policy": name,
        "policy_env_steps": step,
        "policy_sha256": fingerprint,
        "spec": spec_record,
        "summary": res["summary"],
        "invalid_episodes": res["invalid_episodes"],
        "wall_s": time.perf_counter() - t0,
        "per_episode": {k: np.asarray(v).tolist() for k, v in res["per_episode"].items()},
    }
    atomic.write_text(path, json.dumps(record) + "\n")  # a killed evaluation leaves no half-written cache
    return res["summary"]


def read_cache(path: Path) -> dict:
    """A cached evaluation's record; {} when missing or damaged (it is then recomputed)."""
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


def expert_job(
    budget: str,
    out: Path,
    episodes: int,
    shapes: tuple[str, ...],
    setting: str,
    log: Callable[[str], None] = print,
    overrides: dict | None = None,
) -> dict[str, dict]:
    """The scripted expert under the budget's action box (and `overrides`, the agents' `--set`), per
    shape: the baseline row of the report (it reads the simulator's ground truth, so it bounds what
    the task allows, not what a policy sees). Cached in OUT/expert/ like the agents' evaluations,
    keyed by the spec and the settings."""
    cfg = budget_config(budget, "vpm", 0, overrides=overrides)
    key = {"env": presets.config_dict(cfg)["env"], "expert": presets.config_dict(cfg)["expert"]}
    summaries = {}
    for shape in shapes:
        spec = EvalSpec(setting=setting, shape=shape, episodes=episodes, batch=min(episodes, 20))
        path = eval_cache_path(Path(out) / "expert", spec)
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


def budget_config(
    budget: str,
    agent: str,
    seed: int,
    total_env_steps: int | None = None,
    config_hook: Callable[[presets.RunConfig], presets.RunConfig] | None = None,
    overrides: dict | None = None,
) -> presets.RunConfig:
    """The run configuration of `agent` and `seed` under `budget`, trained for `total_env_steps` when
    given (the comparison at a larger budget than the preset's, e.g. curves still rising at its end),
    with `overrides` ({config path: value}, `--set`: the comparison under a variant, e.g. another
    expert) applied to every agent alike, then passed through `config_hook` (tests shrink runs with it)."""
    cfg = presets.make(agent, budget, seed)
    if total_env_steps is not None:
        cfg = presets.with_overrides(cfg, {"train.loop.total_env_steps": total_env_steps})
    if overrides:
        cfg = presets.with_overrides(cfg, overrides)
    return config_hook(cfg) if config_hook else cfg


def report_dir_of(out: Path, teacher_free: int | None = None) -> Path:
    """Where the report goes: `out`, or with `teacher_free` `out`/teacher-free (its forks' report)."""
    return Path(out) / TEACHER_FREE if teacher_free else Path(out)


def run_dir_of(out: Path, agent: str, seed: int, teacher_free: int | None = None) -> Path:
    """Where the run of `agent` and `seed` lives; with `teacher_free`, its fork without the teacher."""
    return report_dir_of(out, teacher_free) / "runs" / f"{agent}-s{seed}"


def teacher_free_config(cfg: presets.RunConfig, steps: int) -> presets.RunConfig:
    """`cfg` (a run that keeps its teacher to its end) trained `steps` env steps further, the teacher
    annealed away over the first half: the cloning weight and the expert's share of environments fall
    from 1 to 0, and the actor is held to its copy at the run's end with the weight the cloning term
    gives up (`train.sac.anchor_weight` = the cloning weight), so the last half is the agent's own.
    At the `cpu-long` budget with 32,000 steps this is docs/learners.md's recipe."""
    if steps < 2:
        raise ConfigError(f"--teacher-free must be >= 2 env steps (the anneal takes the first half), got {steps}")
    if not cfg.train.demo.enabled or cfg.train.sac.bc_weight == 0:
        raise ConfigError("--teacher-free: this configuration trains without a teacher; there is none to anneal away")
    if cfg.train.demo.anneal_start is not None:
        raise ConfigError(
            "--teacher-free anneals the teacher itself, after the budget's end: leave train.demo.anneal_start "
            f"and anneal_end unset (got {cfg.train.demo.anneal_start} and {cfg.train.demo.anneal_end})"
        )
    end = cfg.train.loop.total_env_steps
    return presets.with_overrides(
        cfg,
        {
            "train.loop.total_env_steps": end + steps,
            "train.demo.anneal_start": end,
            "train.demo.anneal_end": end + steps // 2,
            "train.sac.anchor_weight": cfg.train.sac.bc_weight,
        },
    )


def job_config(
    budget: str,
    agent: str,
    seed: int,
    out: Path,
    total_env_steps: int | None = None,
    config_hook: Callable[[presets.RunConfig], presets.RunConfig] | None = None,
    overrides: dict | None = None,
    teacher_free: int | None = None,
) -> tuple[presets.RunConfig, Path]:
    """The configuration and directory of the run the report scores for `agent` and `seed`: the
    budget's run, or with `teacher_free` its fork without the teacher."""
    cfg = budget_config(budget, agent, seed, total_env_steps, config_hook, overrides)
    if teacher_free:
        cfg = teacher_free_config(cfg, teacher_free)
    return cfg, run_dir_of(out, agent, seed, teacher_free)


def is_finished(run_dir: Path, total_env_steps: int | None = None) -> bool:
    """The run has finished (with `total_env_steps`, trained for exactly that many env steps: a run of a
    smaller budget is not the one asked for)."""
    run_dir = Path(run_dir)
    if not ((run_dir / "summary.json").is_file() and (run_dir / "best_policy.msgpack").is_file()):
        return False
    return total_env_steps is None or (
        presets.load_config(run_dir / "config.json").train.loop.total_env_steps == total_env_steps
    )


def agent_job(
    budget: str,
    agent: str,
    seed: int,
    out: Path,
    episodes: int,
    shapes: tuple[str, ...],
    setting: str,
    log: Callable[[str], None] = print,
    config_hook: Callable[[presets.RunConfig], presets.RunConfig] | None = None,
    train: bool = True,
    total_env_steps: int | None = None,
    overrides: dict | None = None,
    teacher_free: int | None = None,
) -> dict[str, dict]:
    """Train (or reuse / resume) one agent and seed, then evaluate it per shape: {shape: summary}.
    ``train`` False evaluates a finished run only. ``total_env_steps`` replaces the budget's (a finished
    run of fewer steps is trained longer from its checkpoint); ``overrides`` as in `budget_config`;
    ``teacher_free`` forks the finished run and trains that many env steps more without the teacher
    (`teacher_free_config`), and the fork is evaluated. Module-level and picklable, so `--jobs` can run
    it in a worker process."""
    cfg = budget_config(budget, agent, seed, total_env_steps, config_hook, overrides)
    run_dir = run_dir_of(out, agent, seed)
    stages = [(cfg, run_dir, None)]
    if teacher_free:
        fork_dir = run_dir_of(out, agent, seed, teacher_free)
        stages.append((teacher_free_config(cfg, teacher_free), fork_dir, ForkSource(run_dir)))
    for stage_cfg, stage_dir, fork in stages:
        total = stage_cfg.train.loop.total_env_steps
        if train:
            train_or_reuse(stage_cfg, stage_dir, log, fork)
        elif not is_finished(stage_dir, total):
            raise ConfigError(f"{stage_dir} has not finished training ({total:,} env steps)")
    cfg, run_dir, _ = stages[-1]  # the run the table scores: the fork, when there is one
    summaries = {}
    for shape in shapes:
        spec = EvalSpec(setting=setting, shape=shape, episodes=episodes, batch=min(episodes, 20))
        s = summaries[shape] = evaluate_run(cfg, run_dir, spec, log)
        log(
            f"{agent} seed {seed} {shape}: success {s['success']['mean']:.2f}, "
            f"reward {s['reward']['mean']:.1f}, overshoot {s['overshoot']['mean']:.2f}, "
            f"distance {s['distance']['mean']:.2f}"
        )
    return summaries


def _job(kind: str, *args, **kwargs):
    """One call of the pool: an agent's training and evaluation, or the expert's evaluation (module-level
    and picklable, for worker processes)."""
    return {"agent": agent_job, "expert": expert_job}[kind](*args, **kwargs)


def run_jobs(fn: Callable, calls: list[tuple[tuple, dict]], jobs: int) -> list:
    """`fn(*args, **kwargs)` for each call, in order; with jobs > 1 in that many worker processes
    (spawned: JAX is not fork-safe), each compiling its own functions. The first failure cancels the
    jobs not yet started and is raised, naming the call."""
    if jobs < 1:
        raise ConfigError(f"jobs must be >= 1, got {jobs}")
    if jobs == 1:
        return [fn(*args, **kwargs) for args, kwargs in calls]
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=min(jobs, len(calls)), mp_context=ctx) as pool:
        futures = [pool.submit(fn, *args, **kwargs) for args, kwargs in calls]
        for (args, _), fut in zip(calls, futures):
            try:
                fut.result()
            except Exception as e:
                for f in futures:
                    f.cancel()
                raise RuntimeError(f"job {args} failed: {type(e).__name__}: {e}") from e
        return [f.result() for f in futures]


def _log_line(prefix: str, line: str) -> None:
    print(f"{prefix}{line}", flush=True)


def plan(
    budget: str,
    seeds: int,
    out: Path,
    agents: tuple[str, ...] = SCHEDULE,
    episodes: int | None = None,
    total_env_steps: int | None = None,
    overrides: dict | None = None,
    teacher_free: int | None = None,
) -> list[str]:
    """One shell command per job (each agent and seed: train, then evaluate; the expert's row), then the
    command that builds the report from them. The jobs are independent: run them anywhere that shares
    `out`, in any order, and the report last (or at any time, for the runs finished so far)."""
    ep = f" --episodes {episodes}" if episodes else ""
    ep += f" --total-env-steps {total_env_steps}" if total_env_steps else ""
    ep += f" --teacher-free {teacher_free}" if teacher_free else ""
    ep += presets.set_flag(overrides)
    base = f"mjx-push reproduce --budget {budget} --out {out}{ep}"
    jobs = [f"{base} --job {agent}:{seed}" for seed in range(seeds) for agent in dict.fromkeys(agents)]
    return jobs + [
        f"{base} --job expert",
        f"{base} --seeds {seeds} --agents {' '.join(dict.fromkeys(agents))} --report-only",
    ]


def reproduce(
    budget: str,
    seeds: int,
    out: Path,
    episodes: int | None = None,
    agents: tuple[str, ...] = SCHEDULE,
    shapes: tuple[str, ...] = PAPER_SHAPES,
    setting: str = "difficult",
    log: Callable[[str], None] = print,
    config_hook: Callable[[presets.RunConfig], presets.RunConfig] | None = None,
    jobs: int = 1,
    expert: bool = True,
    report_only: bool = False,
    total_env_steps: int | None = None,
    overrides: dict | None = None,
    teacher_free: int | None = None,
) -> Path:
    """Train + evaluate every agent for `seeds` seeds (`jobs` of them at a time, in worker processes
    when > 1), and the scripted expert as a baseline row (``expert``); returns the report's path
    (in `out`, or with ``teacher_free`` in `out`/teacher-free, scoring the forks without the teacher).
    ``report_only``: train nothing; the report holds the runs that have finished (evaluated here if not
    yet) and names the others. `overrides` ({config path: value}) change every agent's configuration
    and the expert's alike (`--set`). `config_hook` lets tests shrink the runs (it must be picklable
    when jobs > 1)."""
    if seeds < 1:
        raise ConfigError(f"seeds must be >= 1, got {seeds}")
    for a in agents:
        if a not in AGENTS:
            raise ConfigError(f"agents must be among {AGENTS}, got {a!r}")
    out = Path(out)
    episodes = episodes or EVAL_EPISODES[budget]
    t0 = time.perf_counter()
    agents = tuple(dict.fromkeys(agents))  # scheduling order as given, once each
    items = [(agent, seed) for seed in range(seeds) for agent in agents]
    scored = {
        (a, s): job_config(budget, a, s, out, total_env_steps, config_hook, overrides, teacher_free) for a, s in items
    }
    report_dir = report_dir_of(out, teacher_free)
    missing = []
    if report_only:
        missing = [i for i in items if not is_finished(scored[i][1], scored[i][0].train.loop.total_env_steps)]
        items = [i for i in items if i not in missing]
        for i in missing:
            log(f"{scored[i][1]} has not finished: left out of the report")
        if not items:
            raise ConfigError(f"no finished run in {report_dir / 'runs'} for agents {agents} and {seeds} seed(s)")
    calls = []
    for agent, seed in items:
        # In a worker, `log` (often a rich console) stays behind: lines go to stdout, prefixed.
        job_log = log if jobs == 1 else functools.partial(_log_line, f"[{agent} s{seed}] ")
        calls.append(
            (
                ("agent", budget, agent, seed, out, episodes, shapes, setting),
                {
                    "log": job_log,
                    "config_hook": config_hook,
                    "train": not report_only,
                    "total_env_steps": total_env_steps,
                    "overrides": overrides,
                    "teacher_free": teacher_free,
                },
            )
        )
    if expert:  # last: the first worker to finish an agent takes it, beside the last agents
        calls.append(
            (
                ("expert", budget, out, episodes, shapes, setting),
                {"log": log if jobs == 1 else functools.partial(_log_line, "[expert] "), "overrides": overrides},
            )
        )
    summaries = run_jobs(_job, calls, jobs)
    done = {a for a, _ in items}
    results: dict[str, dict[str, list]] = {a: {s: [] for s in shapes} for a in AGENTS if a in done}
    for (agent, _), per_shape in zip(items, summaries):
        for shape in shapes:
            results[agent][shape].append(per_shape[shape])
    if expert:
        results["expert"] = {s: [v] for s, v in summaries[-1].items()}
    fork = scored[items[0]][0].train  # with teacher_free, every fork's schedule (one budget)
    meta = {
        "budget": budget,
        "total_env_steps": budget_config(
            budget, "vpm", 0, total_env_steps, overrides=overrides
        ).train.loop.total_env_steps,
        "budget_total_changed": total_env_steps is not None,
        "overrides": overrides or {},
        "teacher_free": teacher_free,
        # (anneal start, anneal end, total) of the forks: the report's account of the schedule
        "teacher_free_env_steps": [fork.demo.anneal_start, fork.demo.anneal_end, fork.loop.total_env_steps]
        if teacher_free
        else None,
        "seeds": seeds,
        "jobs": jobs,
        "episodes": episodes,
        "setting": setting,
        "agents": list(results),
        "missing_runs": [f"{a}-s{s}" for a, s in missing],
        "shapes": list(shapes),
        "wall_s": time.perf_counter() - t0,
        "machine": f"{platform.machine()}, {__import__('os').cpu_count()} CPU cores, "
        f"jax backend {__import__('jax').default_backend()}",
    }
    runs = {a: [scored[a2, s][1] for a2, s in items if a2 == a] for a in results if a in AGENTS}
    path = write_report(report_dir, results, meta, runs)
    (report_dir / "reproduce.json").write_text(json.dumps(meta, indent=2) + "\n")
    return path

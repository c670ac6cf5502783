"""`mjx-push protocol FOLDER`: the runs of a pre-registered comparison, each recorded in FOLDER as it ends.

A protocol is fixed in `FOLDER/protocol.json` before any of its runs (the preset, the agents, the
training seeds, the test episodes, the actor scored, the statistics; docs/comparison-protocol.md says
why each). This module trains every agent x seed at the preset (in `OUT/runs/<agent>-s<seed>`, reused
when finished, resumed when interrupted), scores the declared actor on the protocol's test episodes per
shape, and writes `FOLDER/runs/<agent>-s<seed>.json` at once: status, env steps, the commit that ran it,
the per-shape summaries and per-episode values. A run that fails is written as failed with its reason,
so no run of the protocol goes unreported. `FOLDER/expert.json` holds the scripted expert on the same
episodes. The tables are then printed from FOLDER alone (`python -m mjx_push.train.comparison.tables FOLDER`).

Runs are independent: `plan` lists one command per run for any scheduler that shares OUT and FOLDER.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from mjx_push.train import presets
from mjx_push.train.runs import atomic
from mjx_push.train.runs.checkpoints import saved_steps
from mjx_push.train.comparison.tables import Protocol, load_protocol
from mjx_push.train.evaluate import ExpertPolicy, evaluate
from mjx_push.train.episodes import EvalSpec
from mjx_push.train.provenance import source_commit
from mjx_push.train.comparison.cache import eval_cache_path, evaluate_run, read_cache
from mjx_push.train.comparison.jobs import run_jobs
from mjx_push.train.comparison.reproduce import train_or_reuse
from mjx_push.train.comparison.study import SCHEDULE
from mjx_push.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class ProtocolRuns:
    """Everything a protocol's jobs need, as one value: the committed data folder, where the runs train,
    and how to log. `config_hook` lets tests shrink the runs (picklable when jobs > 1)."""

    folder: Path
    out: Path
    log: Callable[[str], None] = print
    config_hook: Callable[[presets.RunConfig], presets.RunConfig] | None = None

    @functools.cached_property
    def protocol(self) -> Protocol:
        """FOLDER/protocol.json, read once (it never changes under a protocol's runs)."""
        return load_protocol(Path(self.folder))

    def config(self, agent: str, seed: int) -> presets.RunConfig:
        """The run's configuration: the protocol's preset for this agent and seed with the protocol's own
        `set` items, nothing else changed."""
        p = self.protocol
        if agent not in p.agents or seed not in p.seeds:
            raise ConfigError(f"{agent}:{seed} is not a run of protocol {p.version} ({p.agents}, seeds {p.seeds})")
        cfg = presets.make(agent, p.preset, seed)
        if p.sets:
            try:
                cfg = presets.with_overrides(cfg, presets.parse_overrides(p.sets))
            except ConfigError as e:
                raise ConfigError(f"{Path(self.folder) / 'protocol.json'}: field 'set': {e}") from e
        cfg = self.config_hook(cfg) if self.config_hook else cfg
        if cfg.train.loop.total_env_steps != p.env_steps:
            raise ConfigError(
                f"preset {p.preset!r} trains {cfg.train.loop.total_env_steps:,} env steps, protocol {p.version} "
                f"declares {p.env_steps:,}: the protocol and the code that runs it disagree"
            )
        return cfg

    def run_dir(self, agent: str, seed: int) -> Path:
        return Path(self.out) / "runs" / f"{agent}-s{seed}"

    def record_path(self, agent: str, seed: int) -> Path:
        return Path(self.folder) / "runs" / f"{agent}-s{seed}.json"

    def spec(self, shape: str) -> EvalSpec:
        p = self.protocol
        return EvalSpec(
            setting=p.setting,
            shape=shape,
            episodes=p.episodes_per_shape,
            seed=p.test_seed,
            batch=min(20, p.episodes_per_shape),
        )


def _write(path: Path, record: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(path, json.dumps(record, indent=1) + "\n")


def _shape_record(summary: dict, per_episode: dict) -> dict:
    return {"summary": summary, "per_episode": {k: np.asarray(v).tolist() for k, v in per_episode.items()}}


def run_job(runs: ProtocolRuns, agent: str, seed: int) -> dict:
    """Train (or reuse, or resume) one run of the protocol, score its declared actor per shape on the
    test episodes and write its record; returns the record. A finished record is never redone. Any
    error is recorded as a failed run (with the env steps reached and the reason), then raised."""
    path = runs.record_path(agent, seed)
    if (recorded := read_cache(path)).get("status") == "finished":
        runs.log(f"{agent} seed {seed}: finished, recorded in {path}")
        return recorded
    p = runs.protocol
    run_dir = runs.run_dir(agent, seed)
    base = {"agent": agent, "seed": seed, "protocol": p.version, "commit": source_commit() or "unknown"}
    _write(path, {**base, "status": "training", "env_steps": _reached(run_dir), "note": f"training in {run_dir}"})
    try:
        cfg = runs.config(agent, seed)
        train_or_reuse(cfg, run_dir, runs.log)
        shapes = {}
        for shape in p.shapes:
            spec = runs.spec(shape)
            evaluate_run(cfg, run_dir, spec, runs.log, policy=p.actor)
            cached = read_cache(eval_cache_path(run_dir, spec))
            shapes[shape] = _shape_record(cached["summary"], cached["per_episode"])
            s = cached["summary"]
            runs.log(
                f"{agent} seed {seed} {shape}: success {s['success']['mean']:.2f}, overshoot "
                f"{s['overshoot']['mean']:.2f}, distance {s['distance']['mean']:.2f}"
            )
    except Exception as e:
        _write(
            path,
            {**base, "status": "failed", "env_steps": _reached(run_dir), "note": f"{type(e).__name__}: {e}"},
        )
        raise
    summary = json.loads((run_dir / "summary.json").read_text())
    record = {
        **base,
        "status": "finished",
        "env_steps": int(summary["env_steps"]),
        "note": "",
        "actor": p.actor,
        "train_wall_s": summary.get("wall_s"),
        "shapes": shapes,
    }
    _write(path, record)
    return record


def _reached(run_dir: Path) -> int:
    """The env steps of the run's last checkpoint (0 before the first)."""
    steps = saved_steps(run_dir / "checkpoints")
    return steps[-1] if steps else 0


def expert_job(runs: ProtocolRuns) -> dict:
    """The scripted expert on the protocol's test episodes, per shape (under the preset's action box),
    written to FOLDER/expert.json: the reference row."""
    path = Path(runs.folder) / "expert.json"
    if (recorded := read_cache(path)).get("shapes"):
        runs.log(f"expert: recorded in {path}")
        return recorded
    p = runs.protocol
    cfg = presets.make("vpm", p.preset, 0)
    cfg = runs.config_hook(cfg) if runs.config_hook else cfg
    shapes = {}
    for shape in p.shapes:
        res = evaluate(ExpertPolicy(cfg), runs.spec(shape))
        shapes[shape] = _shape_record(res["summary"], res["per_episode"])
        runs.log(f"expert {shape}: success {res['summary']['success']['mean']:.2f}")
    record = {"protocol": p.version, "commit": source_commit() or "unknown", "shapes": shapes}
    _write(path, record)
    return record


def jobs_of(protocol: Protocol) -> list[tuple[str, int]]:
    """Every run, seed-major (so the first finished runs cover every agent), agents in SCHEDULE order."""
    agents = [a for a in SCHEDULE if a in protocol.agents] + [a for a in protocol.agents if a not in SCHEDULE]
    return [(agent, seed) for seed in protocol.seeds for agent in agents]


def _job(kind: str, runs: ProtocolRuns, *args):
    return {"run": run_job, "expert": expert_job}[kind](runs, *args)


def run_all(runs: ProtocolRuns, jobs: int = 1) -> None:
    """Every run not yet finished, `jobs` at a time, then the expert's row."""
    for agent, seed in jobs_of(runs.protocol):
        runs.config(agent, seed)  # a bad `set` item is refused before any run starts
    calls = [(("run", runs, agent, seed), {}) for agent, seed in jobs_of(runs.protocol)]
    calls.append((("expert", runs), {}))
    t0 = time.perf_counter()
    run_jobs(_job, calls, jobs)
    runs.log(
        f"protocol {runs.protocol.version}: every run recorded in {runs.folder} ({time.perf_counter() - t0:.0f} s)"
    )


def plan(runs: ProtocolRuns) -> list[str]:
    """One command per run and one for the expert, then the tables' command: for any scheduler that
    shares OUT and FOLDER (each command records its run in FOLDER when it ends)."""
    base = f"mjx-push protocol {runs.folder} --out {runs.out}"
    lines = [f"{base} --job {agent}:{seed}" for agent, seed in jobs_of(runs.protocol)]
    return lines + [f"{base} --job expert", f"python -m mjx_push.train.comparison.tables {runs.folder} --write"]

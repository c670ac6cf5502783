"""The comparison's evaluation cache: each finished evaluation is kept next to its run (or the expert's
folder) as `eval-<setting>-<shape>-<episodes>.json`, tied to the sha256 of the policy it scored, so a
rerun after a crash redoes nothing and new weights under the same name are evaluated again."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from mjx_push.errors import ConfigError
from mjx_push.train import presets
from mjx_push.train.comparison.report import read_training
from mjx_push.train.episodes import EvalSpec
from mjx_push.train.evaluate import DISTANCE_METRICS, METRICS, evaluator_for, summarize
from mjx_push.train.runs import atomic, policies


def scored_policy(run_dir: Path) -> tuple[str, int]:
    """The saved actor the table scores, and its env steps: the best by the current selection rule
    (`loop.improves`) replayed over the run's evaluations (`report.read_training`). A run trained under
    an older rule saved another best; when the current rule picks the final evaluation, `final_policy`
    holds that actor."""
    run_dir = Path(run_dir)
    pick = read_training(run_dir)["selected_env_steps"]
    if pick is None:
        raise ConfigError(f"{run_dir}/metrics.csv records no evaluation: the run has no best policy")
    for name, key in (("best_policy", "best_env_steps"), ("final_policy", "env_steps")):  # train/runs/run.py's records
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


def read_cache(path: Path) -> dict:
    """A cached evaluation's record; {} when missing or damaged (it is then recomputed)."""
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


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

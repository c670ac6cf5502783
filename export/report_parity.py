"""The comparison in both simulators (`mjx-push reproduce --cpu render analytic`): every finished
agent and seed of a reproduction evaluated again in CPU MuJoCo, through its NumPy port, on exactly the
episodes of its MJX evaluation, and a Markdown table of the two side by side (`OUT/report-parity.md`).

Each CPU evaluation is cached next to the run's MJX one (`eval-cpu-<masks>-<setting>-<shape>-<episodes>.json`)
and tied, like it, to the sha256 of the policy's weights, so a rerun redoes nothing. The training side
(`mjx_push.train.comparison`) cannot import this module (layers: mjx_push -> train -> export); the command line
composes the two.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from mjx_push.export import sim_eval
from mjx_push.export.metrics import agreement_by_shape, summarize_records
from mjx_push.errors import ConfigError
from mjx_push.train.runs import atomic
from mjx_push.train.runs import policies
from mjx_push.train.comparison.cache import policy_fingerprint, read_cache
from mjx_push.train.comparison.report import AGENT_NAMES, SHAPE_NAMES
from mjx_push.train.comparison.reproduce import is_finished
from mjx_push.train.comparison.study import Study
from mjx_push.train.episodes import EvalSpec

SOURCES = ("render", "analytic")


def cpu_evaluation(run_dir: Path, setting: str, shape: str, episodes: int, source: str, log: Callable = print) -> dict:
    """The CPU MuJoCo run (mask `source`) of the episodes of the run's cached MJX evaluation, with its
    summary and its agreement with that evaluation: {"summary", "agreement", "records", ...}."""
    from mjx_push.export.numpy_policy import NumpyPolicy

    if source not in SOURCES:
        raise ConfigError(f"mask source must be one of {SOURCES}, got {source!r}")
    run_dir = Path(run_dir)
    mjx_path = run_dir / f"eval-{setting}-{shape}-{episodes}.json"
    mjx = read_cache(mjx_path)
    if not mjx.get("per_episode") or not mjx.get("policy"):
        raise ConfigError(f"{mjx_path}: no MJX evaluation to compare with (run mjx-push reproduce first)")
    fingerprint = policy_fingerprint(run_dir / mjx["policy"])
    if mjx.get("policy_sha256") != fingerprint:
        raise ConfigError(
            f"{mjx_path} belongs to other weights than {run_dir / mjx['policy']}: rerun mjx-push reproduce"
        )
    path = run_dir / f"eval-cpu-{source}-{setting}-{shape}-{episodes}.json"
    cached = read_cache(path)
    if cached.get("policy_sha256") == fingerprint and cached.get("spec") == mjx["spec"] and cached.get("records"):
        log(f"reusing evaluation {path}")
        return cached
    spec = EvalSpec(**{**mjx["spec"], "record": 0})
    policy = NumpyPolicy.from_policy(policies.load_policy(run_dir / mjx["policy"]), {"source": str(run_dir)})
    records = sim_eval.run_cpu(policy, spec, source)
    result = {
        "policy": mjx["policy"],
        "policy_sha256": fingerprint,
        "spec": mjx["spec"],
        "mask_source": source,
        "summary": summarize_records(records),
        "agreement": agreement_by_shape(mjx["per_episode"], records),
        "mjx_summary": mjx["summary"],
        "records": records,
    }
    atomic.write_text(path, json.dumps(result) + "\n")
    a = result["agreement"]["all"]
    log(
        f"{run_dir.name} {shape} CPU MuJoCo ({source} masks): success {a['cpu_success']:.2f} "
        f"(MJX {a['mjx_success']:.2f}), same outcome {a['success_agreement']:.2f}"
    )
    return result


def parity_report(study: Study, runs: list[tuple[str, int]], sources: tuple[str, ...], log: Callable = print) -> Path:
    """Evaluate every finished (agent, seed) of `runs` (the study's budget runs) in CPU MuJoCo per shape
    and mask source on the study's episodes and write OUT/report-parity.md: per agent and shape, success
    in MJX and in CPU MuJoCo (mean over the seeds, each seed's value in brackets), the per-episode
    agreement and the correlation of final distances. Only runs trained for the study's env steps count
    as finished (`reproduce --total-env-steps`: a run not yet trained longer is left out, as in the MJX
    report)."""
    out, shapes, setting, episodes = study.out, study.shapes, study.setting, study.episodes_per_shape
    total = study.budget_env_steps
    rows, left_out = [], []
    for agent, seed in runs:
        run_dir = study.run_dir(agent, seed)
        if not is_finished(run_dir, total):
            left_out.append(run_dir.name)
            continue
        for shape in shapes:
            for source in sources:
                r = cpu_evaluation(run_dir, setting, shape, episodes, source, log)
                rows.append((agent, seed, shape, source, r["agreement"]["all"]))
    if not rows:
        raise ConfigError(f"no finished run in {out / 'runs'} to evaluate in CPU MuJoCo")
    lines = [
        "# The comparison in both simulators",
        "",
        f"Each agent's best actor on the same {episodes} {setting}-case episodes per shape, in MJX (where it",
        "trained) and in CPU MuJoCo (its NumPy port, as `mjx-push deploy` runs it), success within the radius",
        "it trained for. Means over the training seeds, each seed's value in brackets. `same outcome`: the",
        "episodes that succeed or fail in both; `r`: the correlation of the final object-goal distances.",
        "How far one simulator agrees with itself under a sub-millimetre perturbation: docs/parity.md.",
        "",
        "| shape | agent | masks | MJX | CPU MuJoCo | same outcome | r |",
        "|---|---|---|---|---|---|---|",
    ]
    for shape in shapes:
        for agent in dict.fromkeys(a for a, _, _, _, _ in rows):
            for source in sources:
                cell = [a for g, _, sh, so, a in rows if g == agent and sh == shape and so == source]
                if not cell:
                    continue

                def pct(key):
                    vals = [a[key] for a in cell]
                    each = f" ({', '.join(f'{100 * v:.0f}' for v in vals)})" if len(vals) > 1 else ""
                    return f"{100 * sum(vals) / len(vals):.0f} %{each}"

                corr = [a["final_distance_correlation"] for a in cell if a["final_distance_correlation"] is not None]
                r = f"{sum(corr) / len(corr):.2f}" if corr else "-"
                lines.append(
                    f"| {SHAPE_NAMES.get(shape, shape)} | {AGENT_NAMES.get(agent, agent)} | {source} | "
                    f"{pct('mjx_success')} | {pct('cpu_success')} | {pct('success_agreement')} | {r} |"
                )
    if left_out:
        lines += ["", f"Not finished, so not in this table: {', '.join(left_out)}."]
    path = out / "report-parity.md"
    atomic.write_text(path, "\n".join(lines) + "\n")
    log(f"written {path}")
    return path

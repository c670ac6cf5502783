"""The comparison's settings as one value (`Study`): it pickles for worker processes, its plan and run
directories read as before it existed, and no function of the comparison takes a parameter list."""

import ast
import pickle
from pathlib import Path

import pytest

from mjx_push.train import presets
from mjx_push.train.comparison import reproduce as rep
from mjx_push.train.comparison.study import Study, budget_config, teacher_free_config

COMPARISON = Path(__file__).resolve().parents[1] / "train" / "comparison"
MAX_PARAMETERS = 8  # issue 40: settings travel in a Study, not in parameter lists


def _shrink(cfg: presets.RunConfig) -> presets.RunConfig:  # module-level: a hook a worker can unpickle
    return presets.with_overrides(cfg, {"train.loop.eval_episodes": 4})


def test_a_study_round_trips_through_pickle(tmp_path):
    overrides = presets.parse_overrides(["expert.hold_short=true", "env.substeps=[10,600]"])
    study = Study(
        "cpu-long",
        tmp_path,
        seeds=2,
        agents=("vpm", "egru"),
        episodes=5,
        shapes=("cylinder",),
        setting="standard",
        total_env_steps=128000,
        overrides=overrides,
        teacher_free=32000,
        config_hook=_shrink,
    )
    again = pickle.loads(pickle.dumps(study))
    assert again == study and again.config("egru", 1) == study.config("egru", 1)
    assert again.config("egru", 1).train.loop.eval_episodes == 4  # the hook came along
    assert again.job_config("vpm", 0) == study.job_config("vpm", 0)


def test_a_study_normalises_and_refuses_what_reproduce_refused(tmp_path):
    study = Study("smoke", str(tmp_path), agents=("vpm", "egru", "vpm"), shapes=["cylinder"])
    assert study.out == tmp_path and study.agents == ("vpm", "egru") and study.shapes == ("cylinder",)
    assert study.episodes_per_shape == 8 and study.spec("cylinder").batch == 8
    assert Study("cpu", tmp_path, episodes=50).spec("square").batch == 20
    assert study.runs() == [("vpm", 0), ("egru", 0)]
    with pytest.raises(ValueError, match="seeds must be >= 1"):
        Study("smoke", tmp_path, seeds=0)
    with pytest.raises(ValueError, match="agents must be among"):
        Study("smoke", tmp_path, agents=("dqn",))


def test_a_plan_and_the_run_directories_read_as_before_the_study(tmp_path):
    """Lines and paths written by the parameter-list version of reproduce.py, kept verbatim."""
    overrides = presets.parse_overrides(["expert.hold_short=true", "env.substeps=[10,600]"])
    out = tmp_path
    base = f"mjx-push reproduce --budget smoke --out {out}"
    assert rep.plan(Study("smoke", out)) == [
        *(f"{base} --job {a}:0" for a in ("ugru", "vpm", "stacked", "egru")),
        f"{base} --job expert",
        f"{base} --seeds 1 --agents ugru vpm stacked egru --report-only",
    ]
    study = Study(
        "cpu-long",
        out,
        seeds=2,
        agents=("vpm", "egru", "vpm"),
        episodes=5,
        total_env_steps=128000,
        overrides=overrides,
        teacher_free=32000,
    )
    base = (
        f"mjx-push reproduce --budget cpu-long --out {out} --episodes 5 --total-env-steps 128000 "
        "--teacher-free 32000 --set expert.hold_short=true 'env.substeps=[10,600]'"
    )
    assert rep.plan(study) == [
        f"{base} --job vpm:0",
        f"{base} --job egru:0",
        f"{base} --job vpm:1",
        f"{base} --job egru:1",
        f"{base} --job expert",
        f"{base} --seeds 2 --agents vpm egru --report-only",
    ]
    assert rep.plan(Study("paper", out, seeds=3, episodes=7))[-1] == (
        f"mjx-push reproduce --budget paper --out {out} --episodes 7 --seeds 3 --agents ugru vpm stacked egru "
        "--report-only"
    )
    cfg = budget_config("cpu-long", "egru", 1, 128000, None, overrides)
    assert study.config("egru", 1) == cfg and study.run_dir("egru", 1) == out / "runs" / "egru-s1"
    assert study.job_config("egru", 1) == (teacher_free_config(cfg, 32000), out / "teacher-free" / "runs" / "egru-s1")
    assert study.report_dir == out / "teacher-free" and Study("cpu", out).report_dir == out
    plain = Study("cpu-long", out, overrides=overrides)
    assert plain.job_config("ugru", 2) == (
        budget_config("cpu-long", "ugru", 2, overrides=overrides),
        out / "runs" / "ugru-s2",
    )
    assert study.budget_env_steps == 128000 and plain.budget_env_steps == 64000


def _parameters(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    return len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)


def test_no_function_of_the_comparison_takes_more_than_8_parameters():
    files = sorted(COMPARISON.glob("*.py"))
    assert {"study.py", "reproduce.py", "jobs.py", "cache.py"} <= {f.name for f in files}
    wide = [
        f"{f.name}:{node.lineno} {node.name} ({_parameters(node)})"
        for f in files
        for node in ast.walk(ast.parse(f.read_text()))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and _parameters(node) > MAX_PARAMETERS
    ]
    assert not wide, f"more than {MAX_PARAMETERS} parameters (carry them in a Study): {wide}"

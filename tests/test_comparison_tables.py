"""mjx_push.train.comparison.tables: loading a protocol's data folder, the tables, the claims' verdicts and the
generated docs blocks (--write / --check). Synthetic data folders in tmp_path; NumPy only, no JAX."""

import ast
import dataclasses
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from mjx_push.train.comparison import tables as ct
from mjx_push.train.comparison.tables import Bootstrap, BlockError, DataError

AGENTS = ("vpm", "stacked", "ugru", "egru")
SEEDS = (0, 1, 2, 3, 4)
SHAPES = ("cylinder", "square", "rectangular")
EPISODES = 100
BOOT = Bootstrap(reps=300, confidence=0.95, seed=0)  # enough resamples for these checks, and fast
REPO = Path(__file__).resolve().parents[1]


def _tables(seed: int = 0) -> dict[str, dict[str, np.ndarray]]:
    """metric -> agent -> (seeds, shapes): a level per agent, a spread per seed, in the metrics' ranges."""
    rng = np.random.default_rng(seed)
    tables: dict[str, dict[str, np.ndarray]] = {m: {} for m in ct.METRICS}
    for k, agent in enumerate(AGENTS):
        success = np.clip(0.3 + 0.05 * k + rng.normal(0, 0.04, (len(SEEDS), len(SHAPES))), 0, 1)
        tables["success"][agent] = success
        tables["reward"][agent] = -50.0 * (1 - success) - rng.uniform(0, 3, success.shape)
        tables["overshoot"][agent] = 3.0 - 0.4 * k + rng.uniform(0, 0.5, success.shape)
        tables["distance"][agent] = 5.0 - 0.5 * k + rng.uniform(0, 0.5, success.shape)
    return tables


def _shapes(values: dict[str, np.ndarray], n: int = EPISODES) -> dict:
    """The "shapes" field of a run or expert file: values is metric -> (shapes,)."""
    return {
        shape: {
            "summary": {metric: {"mean": float(v[i]), "sem": 0.01, "n": n} for metric, v in values.items()},
            "per_episode": {"success": [0.0] * n},  # carried by real files; ignored
        }
        for i, shape in enumerate(SHAPES)
    }


def make_folder(
    root: Path,
    tables: dict[str, dict[str, np.ndarray]] | None = None,
    statuses: dict[tuple[str, int], str] | None = None,
    notes: dict[tuple[str, int], str] | None = None,
    name: str = "data/v1",
) -> Path:
    """A protocol folder under root; statuses[(agent, seed)] is "finished" by default, MISSING writes no
    file."""
    tables = tables or _tables()
    statuses, notes = statuses or {}, notes or {}
    folder = root / name
    (folder / "runs").mkdir(parents=True)
    protocol = {
        "version": "v1",
        "agents": list(AGENTS),
        "seeds": list(SEEDS),
        "shapes": list(SHAPES),
        "test_seed": 1000003,
        "episodes_per_shape": EPISODES,
        "setting": "difficult",
        "actor": "final_policy",
        "preset": "teacher-free",
        "env_steps": 128000,
        "bootstrap": dataclasses.asdict(BOOT),
    }
    (folder / "protocol.json").write_text(json.dumps(protocol))
    for agent in AGENTS:
        for i, seed in enumerate(SEEDS):
            status = statuses.get((agent, seed), "finished")
            if status == ct.MISSING:
                continue
            run = {
                "agent": agent,
                "seed": seed,
                "status": status,
                "env_steps": 128000 if status == "finished" else 64000,
                "commit": f"abcdef{i}123456",
                "note": notes.get((agent, seed), ""),
            }
            if status == "finished":
                run["shapes"] = _shapes({m: tables[m][agent][i] for m in ct.METRICS})
            (folder / "runs" / f"{agent}-s{seed}.json").write_text(json.dumps(run))
    expert = {m: np.array([0.9, 0.85, 0.8]) if m == "success" else np.array([-6.0, -7.0, -8.0]) for m in ct.METRICS}
    expert["overshoot"], expert["distance"] = np.array([1.0, 1.5, 2.0]), np.array([2.0, 2.5, 3.0])
    (folder / "expert.json").write_text(json.dumps({"shapes": _shapes(expert)}))
    return folder


def _row(table: str, first: str) -> list[str]:
    """The cells of the table row whose first cell is `first`."""
    for line in table.splitlines():
        if line.startswith(f"| {first} |"):
            return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
    raise AssertionError(f"no row {first!r} in\n{table}")


def _interval(cell: str) -> tuple[float, float, float]:
    point, low, high = re.fullmatch(r"(\S+) \[(\S+), (\S+)\]", cell).groups()
    return float(point), float(low), float(high)


def _claim(claims: tuple[ct.Claim, ...], prefix: str) -> ct.Claim:
    return next(c for c in claims if c.name.startswith(prefix))


# --- the module ------------------------------------------------------------------------------------------


def test_imports_no_jax_even_through_its_imports():
    tree = ast.parse(Path(ct.__file__).read_text())
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
    assert not {name.split(".")[0] for name in imported} & {"jax", "jaxlib", "flax", "optax"}
    # Of the package, only the learner's NumPy-only helpers; and nothing they import brings JAX in either
    # (mjx_push/__init__ and train/__init__ only set XLA flags).
    helpers = {
        (node.module, alias.name)
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mjx_push")
        for alias in node.names
    }
    assert helpers <= {("mjx_push.train.runs", "atomic"), ("mjx_push.train.comparison", "seed_stats")}, helpers
    assert not any(isinstance(n, ast.Import) and n.names[0].name.startswith("mjx_push") for n in ast.walk(tree))
    code = "import sys, mjx_push.train.comparison.tables; sys.exit(' '.join(m for m in sys.modules if m.startswith('jax')) or None)"
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_metric_keys_are_train_evaluates():
    tree = ast.parse((REPO / "train" / "evaluate.py").read_text())
    constants = {
        node.targets[0].id: ast.literal_eval(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name)
        if node.targets[0].id in ("METRICS", "DISTANCE_METRICS")
    }
    assert constants == {"METRICS": ct.METRICS, "DISTANCE_METRICS": ct.OPTIONAL_METRICS}


# --- loading ---------------------------------------------------------------------------------------------


def test_load_lists_every_run_and_tables_hold_the_finished_seeds(tmp_path):
    tables = _tables()
    statuses = {("vpm", 1): "failed", ("ugru", 4): "training", ("stacked", 3): ct.MISSING}
    results = ct.load(make_folder(tmp_path, tables, statuses))
    assert results.protocol.agents == AGENTS and results.protocol.bootstrap == BOOT
    assert [(r.agent, r.seed) for r in results.runs] == [(a, s) for a in AGENTS for s in SEEDS]
    assert [results.run(a, s).status for a, s in statuses] == ["failed", "training", "missing"]
    assert results.run("stacked", 3).env_steps is None and results.run("vpm", 1).env_steps == 64000
    np.testing.assert_array_equal(results.table("egru", "success"), tables["success"]["egru"])
    np.testing.assert_array_equal(results.table("vpm", "reward"), np.delete(tables["reward"]["vpm"], 1, axis=0))
    assert results.table("ugru", "overshoot").shape == (4, 3)
    np.testing.assert_array_equal(results.expert_row("success"), [0.9, 0.85, 0.8])
    with pytest.raises(dataclasses.FrozenInstanceError):
        results.runs = ()
    with pytest.raises(KeyError, match="overshoot_corrections"):
        results.table("egru", "overshoot_corrections")


def _edit(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def _write(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data))


BAD_DATA = {
    "missing metric": (
        lambda f: _edit(f / "runs/egru-s1.json", lambda d: d["shapes"]["square"]["summary"].pop("overshoot")),
        ["runs/egru-s1.json", "'shapes.square.summary.overshoot' missing"],
    ),
    "finished run without a shape": (
        lambda f: _edit(f / "runs/ugru-s0.json", lambda d: d["shapes"].pop("rectangular")),
        ["runs/ugru-s0.json", "'shapes.rectangular' missing"],
    ),
    "agent not in the protocol": (
        lambda f: _write(f / "runs/ppo-s0.json", {}),
        ["runs/ppo-s0.json", "agent 'ppo' seed 0 is not in", "protocol.json"],
    ),
    "seed not in the protocol": (
        lambda f: _write(f / "runs/vpm-s7.json", {}),
        ["runs/vpm-s7.json", "agent 'vpm' seed 7 is not in"],
    ),
    "n differs from episodes_per_shape": (
        lambda f: _edit(f / "runs/egru-s0.json", lambda d: d["shapes"]["cylinder"]["summary"]["success"].update(n=99)),
        ["runs/egru-s0.json", "'shapes.cylinder.summary.success.n'", "99", "episodes_per_shape"],
    ),
    "agent disagrees with the name": (
        lambda f: _edit(f / "runs/vpm-s2.json", lambda d: d.update(agent="egru")),
        ["runs/vpm-s2.json", "field 'agent'", "disagrees with the file's name"],
    ),
    "seed disagrees with the name": (
        lambda f: _edit(f / "runs/vpm-s2.json", lambda d: d.update(seed=3)),
        ["runs/vpm-s2.json", "field 'seed'", "disagrees"],
    ),
    "unknown status": (
        lambda f: _edit(f / "runs/stacked-s4.json", lambda d: d.update(status="done")),
        ["runs/stacked-s4.json", "field 'status'", "'done'"],
    ),
    "success in percent": (
        lambda f: _edit(
            f / "runs/egru-s3.json", lambda d: d["shapes"]["square"]["summary"]["success"].update(mean=45.0)
        ),
        ["runs/egru-s3.json", "'shapes.square.summary.success.mean'", "out of range"],
    ),
    "finished short of the protocol's steps": (
        lambda f: _edit(f / "runs/egru-s3.json", lambda d: d.update(env_steps=1000)),
        ["runs/egru-s3.json", "field 'env_steps'", "128000"],
    ),
    "protocol field missing": (
        lambda f: _edit(f / "protocol.json", lambda d: d.pop("episodes_per_shape")),
        ["protocol.json", "'episodes_per_shape' missing"],
    ),
    "bootstrap confidence": (
        lambda f: _edit(f / "protocol.json", lambda d: d["bootstrap"].update(confidence=95)),
        ["protocol.json", "'bootstrap.confidence'"],
    ),
    "actor not a policy": (
        lambda f: _edit(f / "protocol.json", lambda d: d.update(actor="best")),
        ["protocol.json", "'actor'", "final_policy"],
    ),
    "set not PATH=VALUE items": (
        lambda f: _edit(f / "protocol.json", lambda d: d.update(set=["env.perturb.latency"])),
        ["protocol.json", "'set'", "PATH=VALUE"],
    ),
    "preset missing": (
        lambda f: _edit(f / "protocol.json", lambda d: d.pop("preset")),
        ["protocol.json", "'preset' missing"],
    ),
    "expert without a metric": (
        lambda f: _edit(f / "expert.json", lambda d: d["shapes"]["cylinder"]["summary"].pop("reward")),
        ["expert.json", "'shapes.cylinder.summary.reward' missing"],
    ),
    "run file not JSON": (
        lambda f: (f / "runs/vpm-s0.json").write_text("{"),
        ["runs/vpm-s0.json", "not valid JSON"],
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_DATA))
def test_bad_data_is_refused_naming_the_file_and_field(tmp_path, case):
    break_it, expected = BAD_DATA[case]
    folder = make_folder(tmp_path)
    ct.load(folder)  # good before
    break_it(folder)
    with pytest.raises(DataError) as error:
        ct.load(folder)
    for text in expected:
        assert text in str(error.value), (text, str(error.value))


def test_unfinished_runs_need_no_scores_and_a_missing_folder_is_named(tmp_path):
    folder = make_folder(tmp_path, statuses={("egru", 0): "failed"})
    results = ct.load(folder)
    assert results.run("egru", 0).scores == {}
    with pytest.raises(DataError, match="nowhere.*not a data folder"):
        ct.load(tmp_path / "nowhere")


def test_a_protocol_before_its_expert_row_loads_and_shows_the_row_missing(tmp_path):
    folder = make_folder(tmp_path)
    (folder / "expert.json").unlink()
    results = ct.load(folder)
    assert results.expert is None
    with pytest.raises(KeyError, match="expert's row has not been scored"):
        results.expert_row("success")
    assert re.search(r"^\| expert \| missing \|", ct.success_table(results), re.M)
    expert_rows = [line for line in ct.metrics_table(results).splitlines() if "| expert |" in line]
    assert len(expert_rows) == 3 and all(line.endswith("| — | — | — | — |") for line in expert_rows), expert_rows


# --- tables ----------------------------------------------------------------------------------------------


def test_runs_table_shows_every_run_with_its_status(tmp_path):
    statuses = {("vpm", 1): "failed", ("ugru", 4): "training", ("stacked", 3): ct.MISSING}
    notes = {("vpm", 1): "NaN critic loss | at 64k steps"}
    tables = _tables()
    table = ct.runs_table(ct.load(make_folder(tmp_path, tables, statuses, notes)))
    rows = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| agent")]
    assert len(rows) == len(AGENTS) * len(SEEDS)
    assert re.search(
        r"^\| VPM \| 1 \| failed \| 64000 \| abcdef1 \| — \| — \| — \| — \| NaN critic loss \\\| at 64k steps \|$",
        table,
        re.M,
    )
    assert re.search(r"^\| uGRU \| 4 \| training \| 64000 \| abcdef4 \| — \| — \| — \| — \|  \|$", table, re.M)
    assert re.search(r"^\| Stacked \| 3 \| missing \| — \| — \| — \| — \| — \| — \|  \|$", table, re.M)
    finished = _row(table, "eGRU")
    assert finished[:6] == ["eGRU", "0", "finished", "128000", "abcdef0", "—"]  # no train_wall_s recorded
    assert finished[6:9] == [f"{v * 100:.1f}" for v in tables["success"]["egru"][0]]
    assert "20 runs (4 agents x 5 training seeds): 17 finished, 1 failed, 1 training, 1 missing." in table
    assert "17 finished runs hold 0.0 h in all" not in table and "0 finished runs hold 0.0 h in all" in table


def test_runs_table_shows_each_runs_training_time_and_their_sum(tmp_path):
    folder = make_folder(tmp_path, statuses={("vpm", 1): "failed"})
    _edit(folder / "runs/egru-s0.json", lambda d: d.update(train_wall_s=5400.0))
    _edit(folder / "runs/vpm-s0.json", lambda d: d.update(train_wall_s=1830))
    _edit(folder / "runs/vpm-s1.json", lambda d: d.update(train_wall_s=999.0))  # failed: not in the sum
    table = ct.runs_table(ct.load(folder))
    assert _row(table, "eGRU")[5] == "90" and _row(table, "VPM")[5] == "30"
    assert "2 finished runs hold 2.0 h in all" in table
    _edit(folder / "runs/vpm-s0.json", lambda d: d.update(train_wall_s="30 min"))
    with pytest.raises(DataError, match="runs/vpm-s0.json: field 'train_wall_s'.*'30 min'"):
        ct.load(folder)
    _edit(folder / "runs/vpm-s0.json", lambda d: d.update(train_wall_s=-1.0))
    with pytest.raises(DataError, match="field 'train_wall_s'"):
        ct.load(folder)


def _rerun(folder: Path, name: str, agent: str, seed: int, success: list[float]) -> None:
    values = {m: np.array(success) if m == "success" else np.array([-5.0, -6.0, -7.0]) for m in ct.METRICS}
    values["overshoot"], values["distance"] = np.ones(3), np.ones(3)
    run = {"agent": agent, "seed": seed, "status": "finished", "env_steps": 128000, "commit": "abcdef0123456"}
    (folder / "reruns").mkdir(exist_ok=True)
    (folder / "reruns" / name).write_text(json.dumps({**run, "note": "machine 2", "shapes": _shapes(values)}))


def test_a_rerun_shows_under_its_run_and_stays_out_of_the_statistics(tmp_path):
    tables = _tables()
    folder = make_folder(tmp_path, tables)
    before = ct.render_blocks(ct.load(folder))
    assert before["reruns"].startswith("No rerun")
    _rerun(folder, "vpm-s0-machine2.json", "vpm", 0, [0.5, 0.6, 0.7])
    results = ct.load(folder)
    after = ct.render_blocks(results)
    for name in ct.BLOCK_NAMES[:-1]:  # every other table is the protocol's runs alone
        assert after[name] == before[name], name
    table = after["reruns"]
    lines = [line for line in table.splitlines() if line.startswith("| VPM")]
    original = [f"{v * 100:.1f}" for v in tables["success"]["vpm"][0]]
    assert lines[0].split(" | ")[2] == "protocol's run" and lines[0].split(" | ")[5:8] == original
    assert lines[1].split(" | ")[2] == "rerun machine2" and lines[1].split(" | ")[5:8] == ["50.0", "60.0", "70.0"]
    gaps = np.abs(np.array([0.5, 0.6, 0.7]) - tables["success"]["vpm"][0]) * 100
    assert f"mean {np.mean(gaps):.1f}, largest {np.max(gaps):.1f} points over 3 run x shape pairs" in table


@pytest.mark.parametrize(
    "name, agent, seed, message",
    [
        ("vpm-s0.json", "vpm", 0, "<agent>-s<seed>-<label>.json"),
        ("vpm-s9-machine2.json", "vpm", 9, "seed 9 is not in"),
        ("vpm-s1-machine2.json", "vpm", 0, "disagrees with the file's name"),
    ],
)
def test_bad_rerun_files_are_refused_naming_the_file(tmp_path, name, agent, seed, message):
    folder = make_folder(tmp_path)
    _rerun(folder, name, agent, seed, [0.5, 0.6, 0.7])
    with pytest.raises(DataError, match=re.escape(message)) as e:
        ct.load(folder)
    assert name in str(e.value)


def test_success_table_mean_is_the_mean_of_the_seeds_with_an_interval_around_it(tmp_path):
    tables = _tables()
    results = ct.load(make_folder(tmp_path, tables, {("vpm", 1): "failed"}))
    table = ct.success_table(results)
    for agent, label in (("egru", "eGRU"), ("vpm", "VPM")):
        row = _row(table, label)
        scores = results.table(agent, "success") * 100
        assert row[1] == f"{len(scores)}/5"
        for i in range(len(SHAPES)):
            mean, low, high = _interval(row[2 + 2 * i])
            assert mean == float(f"{scores[:, i].mean():.1f}")
            assert low <= mean <= high and low < high
        iqm, low, high = _interval(row[-1])
        assert iqm == float(f"{scipy.stats.trim_mean(scores.ravel(), 0.25):.1f}") and low <= iqm <= high
    seeds = _row(table, "VPM")[3].split(" / ")  # cylinder, in seed order, the failed seed shown as such
    assert seeds == [f"{v * 100:.1f}" if s != 1 else "—" for s, v in enumerate(tables["success"]["vpm"][:, 0])]
    body = [line for line in table.split("\n\n")[0].splitlines()]
    assert body[-1].startswith("| expert | — | 90.0 | — | 85.0 | — | 80.0 | — |")
    assert ct.success_table(results) == table  # deterministic


def test_metrics_table_means_and_expert_rows(tmp_path):
    tables = _tables()
    table = ct.metrics_table(ct.load(make_folder(tmp_path, tables)))
    for metric, label, decimals in (("reward", "mean episode reward", 1), ("overshoot", "overshoot corrections", 2)):
        row = next(line for line in table.splitlines() if line.startswith(f"| {label} | uGRU |"))
        cells = [c.strip() for c in row.split("|")[1:-1]]
        for i in range(len(SHAPES)):
            mean, low, high = _interval(cells[3 + i])
            assert mean == float(f"{tables[metric]['ugru'][:, i].mean():.{decimals}f}") and low <= mean <= high
    assert "| distance corrections | expert | — | 2.00 | 2.50 | 3.00 |" in table


def _dominated(gap: float, square: float = 0.0) -> dict[str, dict[str, np.ndarray]]:
    """eGRU's success = VPM's + gap on cylinder and rectangular (every seed), + square on square."""
    tables = _tables()
    vpm = tables["success"]["vpm"] = np.clip(tables["success"]["vpm"], 0.2, 0.6)
    tables["success"]["egru"] = vpm + np.array([gap, square, gap])
    return tables


def test_improvement_table_on_a_dominated_comparison(tmp_path):
    table = ct.improvement_table(ct.load(make_folder(tmp_path, _dominated(0.35))))
    row = _row(table, "P(eGRU > VPM)")
    assert row[1] == "5 vs 5"
    assert row[2] == row[4] == "1.00 [1.00, 1.00]"  # every seed above every seed
    point, low, high = _interval(row[3])  # equal on square: one half, interval around it
    assert point == 0.5 and low < 0.5 < high


# --- claims ----------------------------------------------------------------------------------------------


def test_c1_holds_on_the_papers_pattern_and_not_on_its_reverse(tmp_path):
    results = ct.load(make_folder(tmp_path, _dominated(0.15)))
    c1 = _claim(ct.claims(results), "C1")
    assert c1.verdict == ct.HOLDS, c1
    assert (
        c1.measured[0].startswith("cylinder: Δ +15.0 [")
        and "lead (paper: lead); interval contains +15.0: yes" in c1.measured[0]
    )
    assert "equal (paper: equal); interval contains +15.0: no" in c1.measured[1]
    assert "| C1 success pattern |" in ct.claims_table(results) and "| holds |" in ct.claims_table(results)
    success = _dominated(0.15)["success"]
    # The reverse: eGRU behind on cylinder and rectangular, and not equal on square: no shape matches.
    reverse = {"egru": success["vpm"], "vpm": success["vpm"] + np.array([0.15, -0.15, 0.15])}
    assert ct.claim_success_pattern(reverse, SHAPES, BOOT).verdict == ct.DOES_NOT_HOLD
    # Swapped only: square still equal, the other two behind: partly.
    swapped = {"egru": success["vpm"], "vpm": success["egru"]}
    assert ct.claim_success_pattern(swapped, SHAPES, BOOT).verdict == ct.PARTLY


def _four(levels: dict[str, list[float]], spread: float = 0.02, seed: int = 0) -> dict[str, np.ndarray]:
    """agent -> (5 seeds, 3 shapes): each shape's level plus a per-seed spread."""
    rng = np.random.default_rng(seed)
    return {agent: np.array(level) + rng.uniform(-spread, spread, (5, 3)) for agent, level in levels.items()}


def test_c2_verdicts_on_hand_built_tables():
    def verdict(tables):
        return ct.claim_highest_success(tables, SHAPES, BOOT).verdict

    others = {"vpm": [0.3] * 3, "stacked": [0.32] * 3, "ugru": [0.4] * 3}
    assert verdict(_four({**others, "egru": [0.5] * 3})) == ct.HOLDS
    # uGRU clearly above eGRU on cylinder: led somewhere.
    assert verdict(_four({**others, "ugru": [0.7, 0.4, 0.4], "egru": [0.5] * 3})) == ct.DOES_NOT_HOLD
    # eGRU's mean highest on cylinder only; on the others uGRU's mean is a bit higher, within the noise.
    close = _four({**others, "ugru": [0.4, 0.41, 0.41], "egru": [0.5, 0.4, 0.4]}, spread=0.1, seed=1)
    close["egru"][:, 1:] = close["ugru"][:, 1:] - 0.01
    claim = ct.claim_highest_success(close, SHAPES, BOOT)
    assert claim.verdict == ct.PARTLY, claim
    assert "highest: yes" in claim.measured[0] and "highest: no; leads eGRU: none" in claim.measured[1]
    # Never the highest, never led: does not hold.
    below = {agent: table.copy() for agent, table in close.items()}
    below["egru"][:, 0] = below["ugru"][:, 0] - 0.01
    assert verdict(below) == ct.DOES_NOT_HOLD


def test_c3_verdicts_on_hand_built_tables():
    def claim(overshoot, distance):
        return ct.claim_fewest_corrections({"overshoot": overshoot, "distance": distance}, SHAPES, BOOT)

    base = {"vpm": [4.0] * 3, "stacked": [3.5] * 3, "ugru": [3.0] * 3}
    halved = claim(_four({**base, "egru": [1.8] * 3}), _four({**base, "egru": [1.9] * 3}))
    assert halved.verdict == ct.HOLDS, halved
    assert "eGRU/VPM 0.4" in halved.measured[0] and "lowest: yes" in halved.measured[0]
    # Lowest everywhere, but at 70 % of VPM's: not "often half".
    assert claim(_four({**base, "egru": [2.8] * 3}), _four({**base, "egru": [2.8] * 3})).verdict == ct.PARTLY
    # Lowest on overshoot only.
    assert claim(_four({**base, "egru": [1.0] * 3}), _four({**base, "egru": [5.0] * 3})).verdict == ct.PARTLY
    assert claim(_four({**base, "egru": [5.0] * 3}), _four({**base, "egru": [5.0] * 3})).verdict == ct.DOES_NOT_HOLD
    zero = {**_four({**base, "egru": [1.0] * 3}), "vpm": np.zeros((5, 3))}
    assert "n/a (VPM 0)" in claim(zero, zero).measured[0]


def test_c4_verdicts_on_hand_built_tables():
    def verdict(tables):
        return ct.claim_gru_rewards(tables, SHAPES, BOOT).verdict

    assert (
        verdict(_four({"vpm": [-30.0] * 3, "stacked": [-28.0] * 3, "ugru": [-15.0] * 3, "egru": [-10.0] * 3}))
        == ct.HOLDS
    )
    same = _four({agent: [-20.0] * 3 for agent in AGENTS}, spread=2.0)
    same = {agent: same["vpm"][::-1] if agent != "vpm" else same["vpm"] for agent in AGENTS}  # equal sets
    assert verdict(same) == ct.DOES_NOT_HOLD
    partly = dict(same, egru=same["vpm"] + 10.0)  # eGRU leads both, uGRU neither
    claim = ct.claim_gru_rewards(partly, SHAPES, BOOT)
    assert claim.verdict == ct.PARTLY and len(claim.measured) == 4 * len(SHAPES)
    assert any(re.fullmatch(r"cylinder: eGRU - VPM Δ \+10\.0 \[\+\S+, \+\S+\], lead", m) for m in claim.measured)


def test_c5_is_untested_in_simulation(tmp_path):
    c5 = ct.claim_real_robot()
    assert c5.verdict == ct.UNTESTED and "no real robot" in c5.measured[0]
    claims = ct.claims(ct.load(make_folder(tmp_path)))
    assert claims[-1] == c5
    assert "| C5 real robot |" in ct.claims_table(ct.load(make_folder(tmp_path, name="data/v2")))


def test_fewer_than_two_finished_seeds_leave_a_claim_untested(tmp_path):
    statuses = {("vpm", s): "failed" for s in SEEDS[1:]}
    results = ct.load(make_folder(tmp_path, statuses=statuses))
    claims = ct.claims(results)
    assert [c.verdict for c in claims] == [ct.UNTESTED] * 5
    for claim in claims[:4]:
        assert "VPM has 1 finished seed(s), a claim needs 2" in claim.measured[0], claim
    assert "untested: VPM has 1 finished seed(s)" in _row(ct.improvement_table(results), "P(eGRU > VPM)")[-1]
    assert _row(ct.improvement_table(results), "P(eGRU > uGRU)")[-1] != "—"  # the others still compared
    # One seed: its score, and no interval over seeds (a degenerate [x, x] would look like certainty).
    row = _row(ct.success_table(results), "VPM")
    (only,) = [x for x in row[3].split(" / ") if x != "—"]
    assert row[2] == f"{only} [one seed]"
    tables = results.tables("success")
    assert ct.claim_success_pattern({"egru": tables["egru"]}, SHAPES, BOOT).measured[0] == (
        "untested: VPM is not in the protocol"
    )


# --- docs blocks and the command line --------------------------------------------------------------------


def _marker(name: str, folder: str = "data/v1") -> str:
    return ct.START_MARKER.format(folder=folder, name=name)


def _doc(names=ct.BLOCK_NAMES, folder: str = "data/v1") -> str:
    parts = ["# Comparison\n\nSome text  \n"]
    for name in names:
        parts.append(f"\n## {name}\n\n{_marker(name, folder)}\nold content\n{ct.END_MARKER}\n\nAfter {name}.\n")
    return "".join(parts)


@pytest.fixture
def repo(tmp_path, monkeypatch):
    """A working directory with data/v1, docs/comparison.md holding every block, and a README holding one."""
    monkeypatch.chdir(tmp_path)
    make_folder(tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "comparison.md").write_text(_doc())
    (tmp_path / "docs" / "other.md").write_text("# No blocks here\n")
    (tmp_path / "README.md").write_text(_doc(["success"]))
    return tmp_path


def test_check_passes_after_write_and_fails_naming_a_changed_block(repo, capsys):
    assert ct.default_files("data/v1") == [Path("README.md"), Path("docs/comparison.md")]
    assert ct.main(["data/v1", "--check"]) == 1  # "old content" everywhere
    assert len(capsys.readouterr().err.strip().splitlines()) == 1 + len(ct.BLOCK_NAMES)
    assert ct.main(["data/v1", "--write"]) == 0
    assert ct.main(["data/v1", "--check"]) == 0
    assert f"{1 + len(ct.BLOCK_NAMES)} generated block(s) of data/v1 up to date in 2 file(s)" in capsys.readouterr().out
    doc = repo / "docs" / "comparison.md"
    text = doc.read_text()
    line = next(line for line in text.splitlines() if line.startswith("| eGRU | 5/5 |"))
    changed = re.sub(r"\d+\.\d", lambda m: f"{float(m[0]) + 0.1:.1f}", line, count=1)
    assert changed != line
    doc.write_text(text.replace(line, changed))
    assert ct.main(["data/v1", "--check"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    start = text.splitlines().index(_marker("success")) + 1
    assert err == [
        f"docs/comparison.md:{start}: block 'success' differs from what "
        "`python -m mjx_push.train.comparison.tables data/v1` prints (rewrite it with --write)"
    ]
    # The command CI runs, as a module in a fresh process.
    done = subprocess.run(
        [sys.executable, "-m", "mjx_push.train.comparison.tables", "data/v1", "--check"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert done.returncode == 1 and "block 'success' differs" in done.stderr


def _outside(text: str, folder: str = "data/v1") -> list[str]:
    """The text outside the folder's generated blocks, as the pieces between them."""
    names = "|".join(ct.BLOCK_NAMES)
    pattern = re.escape(ct.START_MARKER.format(folder=folder, name="NAME")).replace("NAME", f"(?:{names})")
    return re.split(rf"(?ms)^{pattern}$.*?^{re.escape(ct.END_MARKER)}$", text)


def test_write_leaves_everything_outside_the_blocks_byte_identical(repo):
    doc = repo / "docs" / "comparison.md"
    odd = (
        "Trailing spaces   \r\nA form feed \x0c and a separator \u2028 ok\n"
        f"```markdown\n{_marker('nosuchblock')}\n```\n"  # the syntax shown in fenced code: text, not a block
        f"{_marker('runs', 'data/v0')}\nanother protocol's table\n{ct.END_MARKER}\n"
    )
    before = odd + _doc() + "\nNo newline at the end"
    doc.write_bytes(before.encode())
    os.chmod(doc, 0o644)
    assert ct.main(["data/v1", "--write", "--files", str(doc)]) == 0
    after = doc.read_bytes().decode()
    assert _outside(after) == _outside(before) and "another protocol's table" in after
    assert "old content" not in after and ct.render_blocks(ct.load("data/v1"))["claims"] in after
    assert os.stat(doc).st_mode & 0o777 == 0o644
    assert ct.main(["data/v1", "--write", "--files", str(doc)]) == 0
    assert doc.read_bytes().decode() == after  # idempotent
    # A file with Windows line endings keeps them inside the blocks too.
    crlf = repo / "crlf.md"
    crlf.write_bytes(_doc(["runs"]).replace("\n", "\r\n").encode())
    assert ct.main(["data/v1", "--write", "--files", "crlf.md"]) == 0
    written = crlf.read_bytes().decode()
    assert "| VPM | 0 | finished |" in written and "\n" not in written.replace("\r\n", "")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (f"x\n\n{_marker('sucess')}\n{ct.END_MARKER}\n", "doc.md:3: unknown block name 'sucess'"),
        (f"x\n{_marker('runs')}\ntable\n", "doc.md:2: block 'runs' has no end marker"),
        (f"x\n{ct.END_MARKER}\n", "doc.md:2: an end marker without a start marker"),
        (
            f"{_marker('runs')}\n{_marker('claims')}\n{ct.END_MARKER}\n",
            "doc.md:2: a start marker inside block 'runs' opened at line 1",
        ),
        (
            "a\n<!-- generated by: python -m mjx_push.train.comparison.tables data/v1; block runs -->\n",
            "doc.md:2: malformed start marker",
        ),
    ],
    ids=["unknown name", "no end marker", "no start marker", "start inside a block", "malformed marker"],
)
def test_unknown_names_and_unmatched_markers_are_refused_by_file_and_line(repo, capsys, text, message):
    bad = repo / "doc.md"
    bad.write_text(text)
    blocks = ct.render_blocks(ct.load("data/v1"))
    with pytest.raises(BlockError) as error:
        ct.update_file(Path("doc.md"), blocks)
    assert str(error.value).startswith(message), str(error.value)
    with pytest.raises(BlockError):
        ct.check_files([Path("doc.md")], blocks)
    good = repo / "docs" / "comparison.md"
    before = good.read_bytes()
    assert ct.main(["data/v1", "--write", "--files", str(good), "doc.md"]) == 2
    assert message in capsys.readouterr().err
    assert good.read_bytes() == before and bad.read_text() == text  # nothing written


def test_bad_data_exits_2_and_writes_nothing(repo, capsys):
    doc = repo / "docs" / "comparison.md"
    before = doc.read_bytes()
    assert ct.main(["data/nowhere", "--write"]) == 2
    assert "data/nowhere" in capsys.readouterr().err
    _edit(repo / "data/v1/runs/egru-s1.json", lambda d: d["shapes"]["square"]["summary"].pop("distance"))
    assert ct.main(["data/v1", "--write"]) == 2
    assert "'shapes.square.summary.distance' missing" in capsys.readouterr().err
    assert ct.main(["data/v1", "--check"]) == 2
    assert doc.read_bytes() == before


def test_without_a_flag_every_table_is_printed(repo, capsys):
    doc = (repo / "docs" / "comparison.md").read_bytes()
    assert ct.main(["data/v1"]) == 0
    out = capsys.readouterr().out
    for name, table in ct.render_blocks(ct.load("data/v1")).items():
        assert f"## {name}\n\n{table}" in out
    assert (repo / "docs" / "comparison.md").read_bytes() == doc


def test_targets_are_met_by_a_precise_egru_and_not_by_a_middling_one(tmp_path):
    """T1: eGRU >= 95 % on every shape with its interval's lower end >= 90 %; T2: overshoot on cuboids at
    most 60 % of the expert's (expert: 1.5 / 2.0) at success within 3 points of the expert's (85 / 80 %)."""
    tables = _tables()
    tables["success"]["egru"] = np.full((5, 3), 0.97) + np.linspace(-0.01, 0.01, 5)[:, None]
    tables["overshoot"]["egru"] = np.tile([0.5, 0.8, 1.1], (5, 1))  # 0.53 and 0.55 of the expert's
    (t1, _, v1), (t2, measured, v2) = ct.targets(ct.load(make_folder(tmp_path / "a", tables)))
    assert (t1, v1, t2, v2) == ("T1", "met", "T2", "met"), measured
    tables["overshoot"]["egru"] = np.tile([0.5, 1.0, 1.1], (5, 1))  # square: 0.67 of the expert's
    assert [v for _, _, v in ct.targets(ct.load(make_folder(tmp_path / "b", tables)))] == ["met", "not met"]
    tables["success"]["egru"][:, 2] = [0.99, 0.99, 0.99, 0.80, 0.99]  # mean 95.2 %, lower end below 90 %
    assert ct.targets(ct.load(make_folder(tmp_path / "c", tables)))[0][2] == "not met"
    one_seed = {(a, s): ct.MISSING for a in AGENTS for s in SEEDS if s > 0}
    assert [v for _, _, v in ct.targets(ct.load(make_folder(tmp_path / "d", tables, one_seed)))] == ["untested"] * 2
    assert "| T1 |" in ct.targets_table(ct.load(make_folder(tmp_path / "e", tables)))

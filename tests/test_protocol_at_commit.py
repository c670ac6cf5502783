"""benchmarks.protocol_at_commit: a protocol's runs train with the code of its commit (a worktree and an
environment that imports it), and records move between the checkout and the worktree without ever
overwriting one."""

import json
import subprocess

import pytest

from benchmarks import protocol_at_commit as pac


def _folder(root, protocol=None, **recs):
    root.mkdir(parents=True)
    (root / "protocol.json").write_text(json.dumps(protocol or {"version": "v1"}))
    for name, content in recs.items():
        path = root / name.replace("__", "/")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(content))
    return root


def test_records_the_target_lacks_are_copied_and_none_is_overwritten(tmp_path):
    main = _folder(tmp_path / "main", **{"runs__vpm-s0.json": {"a": 1}, "expert.json": {"e": 1}})
    tree = _folder(tmp_path / "tree", **{"runs__vpm-s0.json": {"a": 1}, "runs__egru-s1.json": {"b": 2}})
    assert pac.copy_records(main, tree) == ["expert.json"]
    assert pac.copy_records(tree, main) == ["runs/egru-s1.json"]
    assert json.loads((main / "runs/egru-s1.json").read_text()) == {"b": 2}
    assert pac.copy_records(tree, main) == [] and pac.copy_records(main, tree) == []
    (tree / "runs/vpm-s0.json").write_text(json.dumps({"a": 9}))
    (tree / "runs/ugru-s2.json").write_text("{}")
    with pytest.raises(pac.CommitError, match=r"records differ .*: runs/vpm-s0.json \(nothing copied\)"):
        pac.copy_records(tree, main)
    assert not (main / "runs/ugru-s2.json").exists()


def test_a_run_still_training_is_never_copied_and_its_finished_record_then_is(tmp_path):
    main = _folder(tmp_path / "main")
    tree = _folder(tmp_path / "tree", **{"runs__stacked-s2.json": {"status": "training"}, "expert.json": {"e": 1}})
    assert pac.copy_records(tree, main) == ["expert.json"]
    assert not (main / "runs/stacked-s2.json").exists()
    (tree / "runs/stacked-s2.json").write_text(json.dumps({"status": "finished"}))
    assert pac.copy_records(tree, main) == ["runs/stacked-s2.json"]
    # the other way: the checkout's finished record goes into a worktree that holds the run as training
    # only when that is resolved by hand, never by overwriting
    other = _folder(tmp_path / "other", **{"runs__stacked-s2.json": {"status": "training"}})
    with pytest.raises(pac.CommitError, match="runs/stacked-s2.json as still training"):
        pac.copy_records(main, other)


def test_another_protocol_is_refused(tmp_path):
    main = _folder(tmp_path / "main", {"version": "v1", "seeds": [0, 1]})
    tree = _folder(tmp_path / "tree", {"version": "v1", "seeds": [0, 1, 2]}, **{"runs__vpm-s0.json": {}})
    with pytest.raises(pac.CommitError, match="differ: not the same protocol"):
        pac.copy_records(tree, main)
    assert not (main / "runs").exists()


def _git(repo, *args):
    subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True)


def test_the_environment_imports_the_commits_code_not_the_checkouts(tmp_path, monkeypatch):
    repo = tmp_path / "repo"
    (repo / "probe").mkdir(parents=True)
    (repo / "pyproject.toml").write_text(
        '[build-system]\nrequires = ["setuptools"]\nbuild-backend = "setuptools.build_meta"\n'
        '[project]\nname = "probe"\nversion = "0"\n[tool.setuptools]\npackages = ["probe"]\n'
    )
    (repo / "probe" / "__init__.py").write_text("WHO = 'first'\n")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "first")
    first = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    (repo / "probe" / "__init__.py").write_text("WHO = 'later'\n")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qam", "later")
    monkeypatch.setattr(pac, "REPO", repo)
    out = tmp_path / "out"
    tree = pac.worktree(first[:7], out)
    python = pac.environment(first[:7], out, tree)
    got = subprocess.run(
        [str(python), "-c", "import probe, json; print(probe.WHO, probe.__file__)"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    who, where = got.stdout.split()
    assert who == "first" and where.startswith(str(tree))
    # this environment's packages are shared, not reinstalled
    assert subprocess.run([str(python), "-c", "import numpy"], capture_output=True).returncode == 0
    assert pac.worktree(first[:7], out) == tree  # made once
    with pytest.raises(pac.CommitError, match="not a commit"):
        pac.worktree("nope123", out)


def test_a_rerun_trains_apart_and_is_kept_under_reruns_with_its_note(tmp_path):
    assert pac.parse_rerun("egru:0:machine2") == ("egru", 0, "machine2")
    for bad in ("egru:0", "egru:x:m", "egru:0:Machine 2"):
        with pytest.raises(pac.CommitError, match="--rerun must be AGENT:SEED:LABEL"):
            pac.parse_rerun(bad)
    original = {"status": "finished", "note": ""}
    main = _folder(tmp_path / "main", **{"runs__egru-s0.json": original})
    # the protocol's own worktree holds its records: its finished run would be reused, not trained again
    own = _folder(tmp_path / "own", **{"runs__egru-s0.json": original, "runs__egru-s1.json": {"status": "failed"}})
    with pytest.raises(pac.CommitError, match=r"holds the protocol's records \(runs/egru-s1.json\)"):
        pac.check_rerun_tree(own, main, "egru", 0)
    (own / "runs/egru-s1.json").unlink()
    with pytest.raises(pac.CommitError, match="is the original run's record"):
        pac.check_rerun_tree(own, main, "egru", 0)
    tree = _folder(tmp_path / "tree", **{"runs__egru-s0.json": {"status": "training"}})
    pac.check_rerun_tree(tree, main, "egru", 0)  # its own run, still training: resumed there
    out = tmp_path / "out"
    assert pac.keep_rerun(tree, main, out, "egru", 0, "machine2") is None
    # a failed rerun is not kept: it stays in the worktree and the same command trains it again
    (tree / "runs/egru-s0.json").write_text(json.dumps({"status": "failed", "note": "OOM"}))
    assert pac.keep_rerun(tree, main, out, "egru", 0, "machine2") is None and not (main / "reruns").exists()
    (tree / "runs/egru-s0.json").write_text(json.dumps({"status": "finished", "env_steps": 128000, "note": ""}))
    (out / "runs/egru-s0").mkdir(parents=True)
    (out / "runs/egru-s0/summary.json").write_text(json.dumps({"resumed_from_env_steps": 48000}))
    kept = pac.keep_rerun(tree, main, out, "egru", 0, "machine2")
    assert kept == main / "reruns/egru-s0-machine2.json"
    record = json.loads(kept.read_text())
    assert record["status"] == "finished" and record["note"].startswith(pac.RERUN_NOTE)
    assert "resumed at 48,000 env steps" in record["note"]
    assert json.loads((main / "runs/egru-s0.json").read_text()) == original  # left alone
    assert pac.keep_rerun(tree, main, out, "egru", 0, "machine2") == kept  # the same record again: no change
    (tree / "runs/egru-s0.json").write_text(json.dumps({"status": "finished", "env_steps": 99}))
    with pytest.raises(pac.CommitError, match="egru-s0-machine2.json exists with other contents"):
        pac.keep_rerun(tree, main, out, "egru", 0, "machine2")
    assert json.loads(kept.read_text())["env_steps"] == 128000


def test_rerun_trains_the_one_job_in_its_own_out_and_keeps_only_a_finished_record(tmp_path, monkeypatch):
    """`rerun` end to end, with the worktree, its environment and the training stood in for: the job it
    asks for, the out it claims, what it keeps after a failed and a finished training, what it refuses."""
    repo = tmp_path / "repo"
    folder = _folder(repo / "docs/data/p", **{"runs__egru-s0.json": {"status": "finished", "note": ""}})
    rel = folder.relative_to(repo)
    monkeypatch.setattr(pac, "REPO", repo)
    outcome = {"status": "failed", "note": "boom"}
    calls = []

    def worktree(commit, out):
        tree = out / f"worktree-{commit}"
        (tree / rel / "runs").mkdir(parents=True, exist_ok=True)
        (tree / rel / "protocol.json").write_text((folder / "protocol.json").read_text())
        return tree

    def train(cmd, cwd, env):
        calls.append(cmd)
        (cwd / rel / "runs/egru-s0.json").write_text(json.dumps(outcome))
        return subprocess.CompletedProcess(cmd, 0 if outcome["status"] == "finished" else 1)

    monkeypatch.setattr(pac, "worktree", worktree)
    monkeypatch.setattr(pac, "environment", lambda commit, out, tree: out / "venv/bin/python")
    monkeypatch.setattr(pac.subprocess, "run", train)
    out = tmp_path / "out"
    out.mkdir()
    assert pac.rerun(folder, rel, "abc1234", out, "egru:0:machine2", sync=False) == 1
    assert calls[-1][1:] == ["protocol", str(rel), "--out", str(out), "--job", "egru:0"]
    assert not (folder / "reruns").exists()  # the failed training is not kept
    outcome.update(status="finished", note="")
    assert pac.rerun(folder, rel, "abc1234", out, "egru:0:machine2", sync=False) == 0  # the same command again
    kept = json.loads((folder / "reruns/egru-s0-machine2.json").read_text())
    assert kept["status"] == "finished" and kept["note"] == pac.RERUN_NOTE
    assert json.loads((folder / "runs/egru-s0.json").read_text()) == {"status": "finished", "note": ""}
    n = len(calls)
    assert pac.rerun(folder, rel, "abc1234", out, "egru:0:machine2", sync=False) == 0 and len(calls) == n  # done
    # another rerun in the same out, or a rerun in the protocol's own out, is refused before any work
    with pytest.raises(pac.CommitError, match="is another rerun's"):
        pac.rerun(folder, rel, "abc1234", out, "egru:1:machine2", sync=False)
    protocol_out = tmp_path / "protocol-out"
    (protocol_out / "worktree-abc1234").mkdir(parents=True)
    with pytest.raises(pac.CommitError, match="already holds worktree-abc1234: a rerun trains in an --out of its own"):
        pac.rerun(folder, rel, "abc1234", protocol_out, "egru:1:machine2", sync=False)
    assert len(calls) == n

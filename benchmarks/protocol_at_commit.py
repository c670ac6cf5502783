"""Run a protocol's runs with the code of the commit that fixed it, from today's checkout.

    python -m benchmarks.protocol_at_commit docs/data/comparison-v1 --commit 6b6cab9 --out OUT [--jobs 1]
    python -m benchmarks.protocol_at_commit docs/data/comparison-v1 --commit 6b6cab9 --out OUT --sync
    python -m benchmarks.protocol_at_commit docs/data/robust-v1/plain --commit eeee9bd --out OUT2 --rerun egru:0:machine2

A protocol's runs all train from one commit (docs/comparison-protocol.md), while later commits move
the code that reads their records. This keeps the two apart: a git worktree of COMMIT in
OUT/worktree-COMMIT and a virtual environment in OUT/venv-COMMIT that installs that worktree (without
dependencies) over this environment's packages, so the commit's own code trains, whatever its layout.
Before the runs, the records this checkout already holds are copied into the worktree (finished runs
are not redone); after them, and with `--sync` at any time, records the worktree has and this checkout
lacks are copied back, to be committed. A protocol.json that differs between the two, or a record
that exists on both sides with other contents, is refused and nothing is copied.

`--rerun AGENT:SEED:LABEL` trains one run again (its actor was lost with its machine) in an --out of
its own, whose worktree holds no record of the protocol, and keeps the finished record as
FOLDER/reruns/AGENT-sSEED-LABEL.json with a note saying why (and where it resumed); the run's own
record is left alone. Rerun the same command to resume it.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import sysconfig
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


class CommitError(RuntimeError):
    """The worktree, its environment or the records cannot be set up as asked; the message says why."""


def _settled(path: Path) -> bool:
    """A record that will not change: a run finished or failed (not one still training), or the expert's."""
    try:
        return json.loads(path.read_text()).get("status", "finished") in ("finished", "failed")
    except (OSError, json.JSONDecodeError) as e:
        raise CommitError(f"{path}: not a readable record ({e})") from e


def records(folder: Path) -> dict[str, Path]:
    """A protocol folder's settled records by their path inside it: runs/*.json, reruns/*.json,
    expert.json; a run still training is left where it is (its finished record replaces it there)."""
    found = [*folder.glob("runs/*.json"), *folder.glob("reruns/*.json"), *folder.glob("expert.json")]
    return {str(p.relative_to(folder)): p for p in sorted(found) if _settled(p)}


def plan_copy(source: Path, target: Path) -> list[str]:
    """The records `source` holds and `target` lacks; refused when protocol.json differs between the two
    or a record both hold differs (a record is never overwritten)."""
    protocols = [
        json.loads((f / "protocol.json").read_text()) if (f / "protocol.json").exists() else None
        for f in (source, target)
    ]
    if protocols[0] != protocols[1]:
        raise CommitError(f"{source / 'protocol.json'} and {target / 'protocol.json'} differ: not the same protocol")
    theirs = records(target)
    unsettled = [name for name in records(source) if (target / name).exists() and name not in theirs]
    if unsettled:
        raise CommitError(f"{target} records {', '.join(unsettled)} as still training: finish or remove it first")
    clash = [
        name for name, p in records(source).items() if name in theirs and p.read_bytes() != theirs[name].read_bytes()
    ]
    if clash:
        raise CommitError(f"records differ between {source} and {target}: {', '.join(clash)} (nothing copied)")
    return [name for name in records(source) if name not in theirs]


def copy_records(source: Path, target: Path) -> list[str]:
    names = plan_copy(source, target)
    for name in names:
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        (target / name).write_bytes((source / name).read_bytes())
    return names


def _run(cmd: list[str], **kw) -> None:
    done = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if done.returncode != 0:
        raise CommitError(f"{' '.join(map(str, cmd))} failed:\n{done.stderr.strip()[-2000:]}")


def worktree(commit: str, out: Path) -> Path:
    """OUT/worktree-COMMIT at COMMIT (made once; refused when it holds another commit)."""
    full = subprocess.run(
        ["git", "-C", str(REPO), "rev-parse", "--verify", f"{commit}^{{commit}}"], capture_output=True, text=True
    )
    if full.returncode != 0:
        raise CommitError(f"--commit {commit}: not a commit of {REPO}")
    sha = full.stdout.strip()
    path = out / f"worktree-{commit}"
    if not path.exists():
        _run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(path), sha])
    head = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    if head != sha:
        raise CommitError(f"{path} holds {head[:12] or 'no commit'}, not {commit}: remove it or choose another --out")
    return path


def environment(commit: str, out: Path, tree: Path) -> Path:
    """OUT/venv-COMMIT: the worktree installed editable, its dependencies read from this environment's
    packages (a path file), so nothing is downloaded and the commit's own modules are the ones imported."""
    venv = out / f"venv-{commit}"
    python = venv / "bin" / "python"
    if not python.exists():
        _run([sys.executable, "-m", "venv", "--without-pip", str(venv)])  # pip and setuptools: this environment's
        site = Path(
            subprocess.run(
                [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                capture_output=True,
                text=True,
                check=True,
            ).stdout.strip()
        )
        (site / "_shared_packages.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
        _run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "-e", str(tree)])
    return python


RERUN_NOTE = (
    "trained again from the same commit, preset and seed on another machine, because the original run's actor "
    "was lost with its machine"
)
_RERUN = re.compile(r"(?P<agent>[a-z]+):(?P<seed>0|[1-9][0-9]*):(?P<label>[a-z0-9]+(?:-[a-z0-9]+)*)")


def parse_rerun(text: str) -> tuple[str, int, str]:
    m = _RERUN.fullmatch(text)
    if m is None:
        raise CommitError(f"--rerun must be AGENT:SEED:LABEL (label: a-z, 0-9 and -), got {text!r}")
    return m["agent"], int(m["seed"]), m["label"]


def rerun_target(folder: Path, agent: str, seed: int, label: str) -> Path:
    return folder / "reruns" / f"{agent}-s{seed}-{label}.json"


def claim_rerun_out(out: Path, spec: str, rel: Path) -> None:
    """OUT/rerun.json marks OUT as this rerun's: an OUT that already holds a worktree or runs without it
    (the protocol's own, whose finished run would be reused) or marked for another rerun is refused."""
    marker, mine = out / "rerun.json", {"rerun": spec, "folder": str(rel)}
    if marker.exists():
        if json.loads(marker.read_text()) != mine:
            raise CommitError(f"{out} is another rerun's ({marker.read_text().strip()}): choose another --out")
        return
    used = sorted(p.name for p in out.iterdir() if p.name.startswith("worktree-") or p.name == "runs")
    if used:
        raise CommitError(f"{out} already holds {', '.join(used)}: a rerun trains in an --out of its own")
    marker.write_text(json.dumps(mine) + "\n")


def check_rerun_tree(tree_folder: Path, folder: Path, agent: str, seed: int) -> None:
    """A rerun trains in a worktree of its own: one that holds any other record of the protocol, or the
    run's own record as the checkout has it, is the protocol's (its finished run would be reused)."""
    own = f"runs/{agent}-s{seed}.json"
    others = [name for name in records(tree_folder) if name != own]
    if others:
        raise CommitError(
            f"{tree_folder} holds the protocol's records ({', '.join(others)}): a rerun trains in an --out of its own"
        )
    if (folder / own).exists() and (tree_folder / own).exists():
        if (folder / own).read_bytes() == (tree_folder / own).read_bytes():
            raise CommitError(
                f"{tree_folder / own} is the original run's record: a rerun trains in an --out of its own"
            )


def _finished(path: Path) -> bool:
    return path.exists() and json.loads(path.read_text()).get("status") == "finished"


def keep_rerun(tree_folder: Path, folder: Path, out: Path, agent: str, seed: int, label: str) -> Path | None:
    """The rerun's finished record, copied from the worktree to FOLDER/reruns/ with its note; None while
    it has not finished (a failed one stays in the worktree and the same command trains it again). An
    existing rerun record with other contents is refused, never overwritten."""
    source = tree_folder / "runs" / f"{agent}-s{seed}.json"
    if not _finished(source):
        return None
    record = json.loads(source.read_text())
    note = RERUN_NOTE
    summary = out / "runs" / f"{agent}-s{seed}" / "summary.json"
    resumed = json.loads(summary.read_text()).get("resumed_from_env_steps") if summary.exists() else None
    if resumed:
        note += f"; resumed at {resumed:,} env steps (its summary.json): train wall is the last segment's"
    if record.get("note"):
        note += f"; {record['note']}"
    text = json.dumps({**record, "note": note}, indent=1) + "\n"
    target = rerun_target(folder, agent, seed, label)
    if target.exists() and target.read_text() != text:
        raise CommitError(f"{target} exists with other contents (nothing copied)")
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(text)
    return target


def rerun(folder: Path, rel: Path, commit: str, out: Path, spec: str, sync: bool) -> int:
    agent, seed, label = parse_rerun(spec)
    target = rerun_target(folder, agent, seed, label)
    if _finished(target):
        print(f"{target}: already recorded, nothing redone")
        return 0
    claim_rerun_out(out, spec, rel)
    tree = worktree(commit, out)
    check_rerun_tree(tree / rel, folder, agent, seed)
    code = 0
    if not sync:
        python = environment(commit, out, tree)
        cmd = [str(python.parent / "mjx-push"), "protocol", str(rel), "--out", str(out), "--job", f"{agent}:{seed}"]
        print(f"rerunning at {commit}: {' '.join(cmd)} (in {tree})", flush=True)
        code = subprocess.run(cmd, cwd=tree, env={**os.environ, "PYTHONPATH": ""}).returncode
    kept = keep_rerun(tree / rel, folder, out, agent, seed, label)
    if kept:
        print(f"new record, to commit: {kept}")
    else:
        state = tree / rel / "runs" / f"{agent}-s{seed}.json"
        status = json.loads(state.read_text()) if state.exists() else {"status": "not started"}
        print(f"{agent} s{seed}: {status.get('status')}, not recorded ({status.get('note', '')})")
    return code


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "folder", type=Path, help="the protocol's data folder in this checkout (e.g. docs/data/comparison-v1)"
    )
    p.add_argument("--commit", required=True, help="the commit that fixed the protocol")
    p.add_argument("--out", type=Path, required=True, help="where the worktree, its environment and the runs live")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--sync", action="store_true", help="only copy the worktree's new records back")
    p.add_argument("--rerun", metavar="AGENT:SEED:LABEL", help="train that run again in an --out of its own")
    a = p.parse_args(argv)
    folder = a.folder.resolve()
    try:
        rel = folder.relative_to(REPO)
        out = a.out.resolve()
        out.mkdir(parents=True, exist_ok=True)
        if a.rerun is not None:
            return rerun(folder, rel, a.commit, out, a.rerun, a.sync)
        tree = worktree(a.commit, out)
        if not a.sync:
            for name in copy_records(folder, tree / rel):
                print(f"into the worktree: {name}")
            python = environment(a.commit, out, tree)
            cmd = [str(python.parent / "mjx-push"), "protocol", str(rel), "--out", str(out), "--jobs", str(a.jobs)]
            print(f"running at {a.commit}: {' '.join(cmd)} (in {tree})", flush=True)
            code = subprocess.run(cmd, cwd=tree, env={**os.environ, "PYTHONPATH": ""}).returncode
        else:
            code = 0
        for name in copy_records(tree / rel, folder):
            print(f"new record, to commit: {rel / name}")
    except (CommitError, ValueError) as e:
        print(f"protocol_at_commit: {e}", file=sys.stderr)
        return 2
    return code


if __name__ == "__main__":
    sys.exit(main())

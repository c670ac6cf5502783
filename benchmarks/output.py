"""What every benchmark writes beside its table: the machine it ran on and its JSON file."""

from __future__ import annotations

import json
import platform
import subprocess
from pathlib import Path


def machine() -> dict:
    import jax

    return {"platform": platform.platform(), "backend": jax.default_backend(), "jax": jax.__version__}


def checkout() -> dict | None:
    """The code that ran: this checkout's commit and whether the tree differs from it, a tracked file
    changed or a file git does not ignore added (a new script is code too; None outside a git
    checkout), so a row labelled HEAD can be traced to a commit."""
    root = Path(__file__).resolve().parents[1]
    git = lambda *args: subprocess.run(["git", *args], cwd=root, capture_output=True, text=True)  # noqa: E731
    head = git("rev-parse", "--short", "HEAD")
    if head.returncode != 0:
        return None
    return {
        "commit": head.stdout.strip(),
        "modified": bool(git("status", "--porcelain").stdout),
    }


def write_json(path: Path, payload: dict) -> None:
    """`payload` with the machine's record and the checkout's commit, as indented JSON at `path`
    (folders made), and say where."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**payload, "machine": machine(), "checkout": checkout()}, indent=2) + "\n")
    print(f"wrote {path}")

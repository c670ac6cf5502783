"""What every benchmark writes beside its table: the machine it ran on and its JSON file."""

from __future__ import annotations

import json
import platform
from pathlib import Path


def machine() -> dict:
    import jax

    return {"platform": platform.platform(), "backend": jax.default_backend(), "jax": jax.__version__}


def write_json(path: Path, payload: dict) -> None:
    """`payload` with the machine's record, as indented JSON at `path` (folders made), and say where."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**payload, "machine": machine()}, indent=2) + "\n")
    print(f"wrote {path}")

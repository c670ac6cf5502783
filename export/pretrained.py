"""The trained policies that ship with the package, named ``pretrained:NAME`` wherever a command takes a
policy (`mjx-push eval`, `mjx-push deploy`): exported `.npz` files in ``export/pretrained_policies/``
that reference the package's encoder by its sha256 instead of holding it (`mjx_push.export.policy_file`), so each is
a few hundred kB. Each file's metadata names the run, budget, seed and commit that produced it
(``provenance`` and ``run_config``)."""

from __future__ import annotations

from pathlib import Path
from mjx_push.errors import ConfigError

PREFIX = "pretrained:"
DIRECTORY = Path(__file__).parent / "pretrained_policies"


def available(directory: Path | None = None) -> dict[str, Path]:
    """NAME -> file of every shipped policy."""
    d = Path(directory) if directory is not None else DIRECTORY
    return {p.stem: p for p in sorted(d.glob("*.npz"))} if d.is_dir() else {}


def is_reference(policy) -> bool:
    return str(policy).startswith(PREFIX)


def resolve(policy, directory: Path | None = None) -> Path:
    """``pretrained:NAME`` -> the shipped file; anything else is returned as a Path. An unknown name
    raises ValueError listing the names this version ships."""
    if not is_reference(policy):
        return Path(policy)
    name = str(policy)[len(PREFIX) :]
    ships = available(directory)
    if name not in ships:
        listed = ", ".join(PREFIX + n for n in ships) or "none"
        raise ConfigError(f"unknown pretrained policy {str(policy)!r}: this mjx-push ships {listed}")
    return ships[name]

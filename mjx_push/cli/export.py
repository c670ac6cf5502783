"""`mjx-push export`: a trained policy to one .npz (`mjx_push.export.policy_file.export_policy`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Literal

import tyro

from mjx_push.train.provenance import source_commit

from mjx_push.errors import ConfigError


@dataclasses.dataclass
class Export:
    """Export a trained policy to one .npz of float32 weights + JSON metadata (for NumPy / torch / a robot)."""

    source: Annotated[Path, tyro.conf.arg(metavar="SOURCE"), tyro.conf.Positional]
    """a run directory (its best_policy is exported) or a saved policy (.msgpack, .json or their stem)"""
    out: Annotated[Path, tyro.conf.arg(metavar="OUT.npz"), tyro.conf.Positional]
    """the .npz to write"""
    encoder: Literal["embed", "package"] = "embed"
    """embed the encoder's weights (a self-contained file, ~4 MB), or reference the encoder this package
    ships by its sha256 (a few hundred kB; loading then needs mjx-push installed, at that encoder)"""
    provenance: tuple[str, ...] = ()
    """KEY=VALUE facts to record in the file's provenance beside the source and this checkout's commit
    (e.g. budget=cpu-long trained_commit=7da1b98): what a reader of the file needs to trace it"""

    def _provenance(self) -> dict:
        extra = {}
        for item in self.provenance:
            key, sep, value = item.partition("=")
            if not sep or not key.strip():
                raise ConfigError(f"--provenance takes KEY=VALUE items, got {item!r}")
            extra[key.strip()] = value
        return extra

    def run(self) -> dict:
        from rich.console import Console

        from mjx_push.export.policy_file import FORMAT, FORMAT_VERSION, export_policy
        from mjx_push.train.runs.policies import load_policy

        source = Path(self.source)
        if source.is_dir():
            stem = source / "best_policy"
            if not stem.with_suffix(".msgpack").is_file():
                raise ConfigError(f"SOURCE: run directory {source} has no best_policy.msgpack (has the run finished?)")
        else:
            stem = source.with_suffix("") if source.suffix in (".msgpack", ".json") else source
            if not (source.exists() or stem.with_suffix(".msgpack").exists() or stem.with_suffix(".json").exists()):
                raise ConfigError(
                    f"SOURCE {source}: no such file or directory (a run directory, or a saved "
                    "policy: best_policy.msgpack / .json or their stem)"
                )
        if Path(self.out).suffix != ".npz":
            raise ConfigError(f"OUT.npz must be an .npz path, got {self.out}")
        extra = self._provenance()
        try:
            policy = load_policy(stem)
        except ValueError as e:
            raise ConfigError(f"SOURCE {source}: {e}") from None
        meta = export_policy(
            policy, self.out, encoder=self.encoder, provenance={"source": str(stem), "commit": source_commit(), **extra}
        )
        size = Path(self.out).stat().st_size
        Console().print(
            f"wrote [bold]{self.out}[/] ({size / 1e6:.2f} MB): agent {meta['agent']['kind']}, "
            f"format {FORMAT} version {FORMAT_VERSION}, from {stem}; scores {meta['scores']}"
        )
        return meta

"""`mjx-push protocol FOLDER`: a pre-registered comparison's runs (`mjx_push.train.comparison.protocol`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import tyro

from mjx_push.cli.options import write_plan
from mjx_push.errors import ConfigError


@dataclasses.dataclass
class Protocol:
    """Run a pre-registered comparison: every agent x seed of FOLDER/protocol.json trained at its preset
    and scored on its test episodes, each run recorded in FOLDER/runs/ as it ends (a failed run too),
    the scripted expert in FOLDER/expert.json; then `python -m mjx_push.train.comparison.tables FOLDER` prints the
    tables. Rerunning reuses recorded runs and resumes interrupted ones. Nothing of the protocol can be
    changed from the command line: a new setting is a new protocol version (docs/comparison-protocol.md)."""

    folder: Annotated[Path, tyro.conf.arg(metavar="FOLDER"), tyro.conf.Positional]
    """the protocol's data folder (its protocol.json; the runs' records go to FOLDER/runs/)"""
    out: Annotated[Path, tyro.conf.arg(metavar="DIR")] = Path("outputs/protocol")
    """where the runs train (checkpoints, logs, policies: not committed)"""
    jobs: int = 1
    """runs trained at once, each in its own process (2 on a 2-core CPU)"""
    job: Annotated[str | None, tyro.conf.arg(metavar="AGENT:SEED|expert", help_behavior_hint="(default: all)")] = None
    """run one job only: train and score AGENT with SEED, or score the expert"""
    plan: Annotated[Path | None, tyro.conf.arg(metavar="FILE", help_behavior_hint="(default: none)")] = None
    """write one command per job and the tables' command to FILE, for a scheduler; runs nothing"""

    def run(self) -> None:
        from rich.console import Console

        from mjx_push.train.comparison import protocol as proto
        from mjx_push.train.comparison.tables import DataError

        console = Console()
        runs = proto.ProtocolRuns(self.folder, self.out, log=console.print if self.jobs == 1 else print)
        try:
            p = runs.protocol
        except DataError as e:
            raise ConfigError(str(e)) from None
        if self.jobs < 1:
            raise ConfigError(f"--jobs must be >= 1, got {self.jobs}")
        if self.plan is not None and self.job is not None:
            raise ConfigError("--plan and --job exclude each other")
        for agent in p.agents:  # the preset must give what the protocol declares, before any work
            runs.config(agent, p.seeds[0])
        if self.plan is not None:
            write_plan(self.plan, proto.plan(runs), console.print)
            return
        if self.job == "expert":
            proto.expert_job(runs)
        elif self.job is not None:
            agent, sep, seed = self.job.partition(":")
            if not sep or not seed.isdigit() or (agent, int(seed)) not in proto.jobs_of(p):
                raise ConfigError(
                    f"--job must be AGENT:SEED of protocol {p.version} (agents {p.agents}, seeds {p.seeds}) or "
                    f"'expert', got {self.job!r}"
                )
            proto.run_job(runs, agent, int(seed))
        else:
            proto.run_all(runs, self.jobs)

"""`mjx-push reproduce`: the four agents trained, scored per shape and reported (`mjx_push.train.comparison.reproduce`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import tyro

from mjx_push.cli.options import CpuMasks, check_cpu, flag_errors, set_error, write_plan
from mjx_push.train.config import AgentKind
from mjx_push.train.config import Preset

from mjx_push.errors import ConfigError

if TYPE_CHECKING:
    from mjx_push.train.comparison.study import Study


@dataclasses.dataclass
class Reproduce:
    """Train VPM, Stacked, uGRU and eGRU, evaluate each on the difficult case per shape (cylinder,
    square cuboid, rectangular cuboid) and write a Markdown report with figures (docs/task.md section 7).
    Rerunning reuses finished runs and evaluations and resumes interrupted runs."""

    budget: Preset = "smoke"
    seeds: int = 1
    out: Path | None = None
    """default: outputs/reproduce-<budget>"""
    episodes: int | None = None
    """evaluation episodes per shape (default: 8 for smoke, 100 otherwise)"""
    agents: tuple[AgentKind, ...] = ("ugru", "vpm", "stacked", "egru")
    """agents to train, started in this order (the report keeps the paper's order; by default eGRU starts
    last, so it reuses uGRU's compiled evaluation)"""
    jobs: int = 1
    """agents trained and evaluated at once, each in its own process (on a CPU 2 overlaps one job's
    single-core compilation and updates with the other's work; on one GPU keep 1)"""
    plan: Annotated[Path | None, tyro.conf.arg(metavar="FILE", help_behavior_hint="(default: none)")] = None
    """write one command per job (each agent and seed; the expert's row) and the report's command to
    FILE, one a line, for a scheduler to run on any machine that shares --out; runs nothing"""
    job: Annotated[str | None, tyro.conf.arg(metavar="AGENT:SEED|expert", help_behavior_hint="(default: all)")] = None
    """run one job of the plan only: train and evaluate AGENT with SEED, or evaluate the expert"""
    report_only: bool = False
    """train nothing: build the report from the runs that have finished (evaluating them if needed)"""
    total_env_steps: Annotated[int | None, tyro.conf.arg(metavar="N", help_behavior_hint="(default: the budget's)")] = (
        None
    )
    """train every agent for N env steps instead of the budget's; runs of this --out that finished with
    fewer are trained longer from their last checkpoint (exactly as a run of N from the start, except
    for the evaluation at their earlier end)"""
    teacher_free: Annotated[int | None, tyro.conf.arg(metavar="N", help_behavior_hint="(default: none)")] = None
    """then fork every finished run at its end and train it N env steps more with the teacher annealed
    away over the first N/2 (the actor held to its copy at the fork; the last N/2 are its own); the
    report, in OUT/teacher-free/, scores the forks. The budget's runs are the plain comparison's, reused"""
    set: Annotated[tuple[str, ...], tyro.conf.arg(metavar="PATH=VALUE", help_behavior_hint="(default: none)")] = ()
    """override a field of every agent's run configuration and the expert's (config.json's paths;
    values in JSON), e.g. --set expert.hold_short=true: the comparison under a variant (use its own
    --out: a finished run of another configuration is refused)"""
    cpu: CpuMasks = ()
    """also evaluate every finished agent and seed in CPU MuJoCo (its NumPy port) on the same episodes
    with these mask sources, and write OUT/report-parity.md: both simulators' success side by side,
    per-episode agreement, correlation of final distances (cached next to each run)"""

    def overrides(self) -> dict:
        """`--set` as {path: value}, checked against the budget's configuration of every agent asked for."""
        from mjx_push.train import presets
        from mjx_push.train.comparison.study import budget_config

        try:
            overrides = presets.parse_overrides(self.set)
            for agent in self.agents:
                budget_config(self.budget, agent, 0, overrides=overrides)
        except ValueError as e:
            raise set_error(e) from None
        return overrides

    def study(self) -> Study:
        """The comparison these flags ask for, as the one value the comparison's functions take."""
        from mjx_push.train.comparison.study import Study

        return Study(
            budget=self.budget,
            out=self.out or Path(f"outputs/reproduce-{self.budget}"),
            seeds=self.seeds,
            agents=tuple(self.agents),
            episodes=self.episodes,
            total_env_steps=self.total_env_steps,
            overrides=self.overrides(),
            teacher_free=self.teacher_free,
        )

    def run(self) -> None:
        if self.cpu:
            if self.plan is not None or self.job == "expert":
                raise ConfigError("--cpu evaluates trained agents: not with --plan or --job expert")
            check_cpu(self.cpu)
        self._reproduce()
        if self.cpu:
            self._parity()

    def _reproduce(self) -> None:
        from rich.console import Console

        from mjx_push.train.comparison import reproduce as rep
        from mjx_push.train.comparison.study import AGENTS, budget_config

        console = Console()
        if self.episodes is not None and self.episodes < 1:
            raise ConfigError(f"--episodes must be >= 1, got {self.episodes}")
        if self.jobs < 1:
            raise ConfigError(f"--jobs must be >= 1, got {self.jobs}")
        if self.seeds < 1:
            raise ConfigError(f"--seeds must be >= 1, got {self.seeds}")
        if self.total_env_steps is not None:
            with flag_errors({"loop.total_env_steps": "--total-env-steps"}):
                budget_config(self.budget, "vpm", 0, self.total_env_steps)  # refused here, not in a job
        study = self.study()
        if self.teacher_free is not None:
            for agent in self.agents:  # refused here, not in a job
                study.job_config(agent, 0)
        if sum(x is not None and x is not False for x in (self.plan, self.job, self.report_only or None)) > 1:
            raise ConfigError("--plan, --job and --report-only exclude each other")
        if self.plan is not None:
            write_plan(self.plan, rep.plan(study), console.print)
            return
        if self.job is not None:
            if self.job == "expert":
                rep.expert_job(study, log=console.print)
                return
            agent, sep, seed = self.job.partition(":")
            if not sep or agent not in AGENTS or not seed.isdigit():
                raise ConfigError(
                    f"--job must be AGENT:SEED (AGENT one of {AGENTS}, SEED an int >= 0) or 'expert', got {self.job!r}"
                )
            rep.agent_job(study, agent, int(seed), log=console.print)
            return
        path = rep.reproduce(study, log=console.print, jobs=self.jobs, report_only=self.report_only)
        console.print(f"report: {path}")
        console.print((path.parent / "report.md").read_text(), markup=False, soft_wrap=True)  # verbatim Markdown

    def _parity(self) -> None:
        """The CPU MuJoCo runs of --cpu and OUT/report-parity.md."""
        from rich.console import Console

        from mjx_push.export.report_parity import parity_report

        if self.job is not None:
            agent, _, seed = self.job.partition(":")
            runs = [(agent, int(seed))]
        else:
            runs = [(a, s) for s in range(self.seeds) for a in self.agents]
        path = parity_report(self.study(), runs, tuple(self.cpu), Console().print)
        Console().print(path.read_text(), markup=False, soft_wrap=True)

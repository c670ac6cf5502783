"""`Study`: one comparison's settings as one value (the budget, where its runs live, the seeds, agents,
episodes, shapes and variants), and what follows from them: each agent and seed's configuration and run
directory, the report's folder, the evaluation's episodes. Every function of the comparison takes it,
so a setting is named once, and the jobs carry it to worker processes (a frozen dataclass pickles; a
`config_hook` must be picklable too when jobs > 1)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

from mjx_push.errors import ConfigError
from mjx_push.train import presets
from mjx_push.train.config import AGENT_KINDS
from mjx_push.train.episodes import EvalSpec

AGENTS = AGENT_KINDS
# The order agents start in by default: uGRU and eGRU evaluate with the same compiled programs (one
# network; evaluation draws its own objects), so with two jobs eGRU starts once uGRU is done and loads
# them from the compilation cache instead of compiling them beside it.
SCHEDULE = ("ugru", "vpm", "stacked", "egru")
PAPER_SHAPES = ("cylinder", "square", "rectangular")
EVAL_EPISODES = {"smoke": 8, "cpu": 100, "cpu-long": 100, "teacher-free": 100, "reference": 100, "paper": 100}
TEACHER_FREE = "teacher-free"  # <out>/teacher-free/: the forks without the teacher and their report


def budget_config(
    budget: str,
    agent: str,
    seed: int,
    total_env_steps: int | None = None,
    config_hook: Callable[[presets.RunConfig], presets.RunConfig] | None = None,
    overrides: dict | None = None,
) -> presets.RunConfig:
    """The run configuration of `agent` and `seed` under `budget`, trained for `total_env_steps` when
    given (the comparison at a larger budget than the preset's, e.g. curves still rising at its end),
    with `overrides` ({config path: value}, `--set`: the comparison under a variant, e.g. another
    expert) applied to every agent alike, then passed through `config_hook` (tests shrink runs with it)."""
    cfg = presets.make(agent, budget, seed)
    if total_env_steps is not None:
        cfg = presets.with_overrides(cfg, {"train.loop.total_env_steps": total_env_steps})
    if overrides:
        cfg = presets.with_overrides(cfg, overrides)
    return config_hook(cfg) if config_hook else cfg


def teacher_free_config(cfg: presets.RunConfig, steps: int) -> presets.RunConfig:
    """`cfg` (a run that keeps its teacher to its end) trained `steps` env steps further, the teacher
    annealed away over the first half: the cloning weight and the expert's share of environments fall
    from 1 to 0, and the actor is held to its copy at the run's end with the weight the cloning term
    gives up (`train.sac.anchor_weight` = the cloning weight), so the last half is the agent's own.
    At the `cpu-long` budget with 32,000 steps this is docs/learners.md's recipe."""
    if steps < 2:
        raise ConfigError(f"--teacher-free must be >= 2 env steps (the anneal takes the first half), got {steps}")
    if not cfg.train.demo.enabled or cfg.train.sac.bc_weight == 0:
        raise ConfigError("--teacher-free: this configuration trains without a teacher; there is none to anneal away")
    if cfg.train.demo.anneal_start is not None:
        raise ConfigError(
            "--teacher-free anneals the teacher itself, after the budget's end: leave train.demo.anneal_start "
            f"and anneal_end unset (got {cfg.train.demo.anneal_start} and {cfg.train.demo.anneal_end})"
        )
    end = cfg.train.loop.total_env_steps
    return presets.with_overrides(
        cfg,
        {
            "train.loop.total_env_steps": end + steps,
            "train.demo.anneal_start": end,
            "train.demo.anneal_end": end + steps // 2,
            "train.sac.anchor_weight": cfg.train.sac.bc_weight,
        },
    )


@dataclasses.dataclass(frozen=True)
class Study:
    """One comparison: `agents` x `seeds` runs at `budget` in `out`, each scored on `episodes` (default:
    the budget's `EVAL_EPISODES`) of `setting` per shape of `shapes`. `total_env_steps` replaces the
    budget's (a finished run of fewer steps is trained longer); `overrides` ({config path: value},
    `--set`) change every agent's configuration and the expert's alike; `teacher_free` forks each
    finished run and trains it that many env steps more without the teacher, and the report scores the
    forks (`teacher_free_config`); `config_hook` lets tests shrink the runs."""

    budget: str
    out: Path
    seeds: int = 1
    agents: tuple[str, ...] = SCHEDULE
    episodes: int | None = None
    shapes: tuple[str, ...] = PAPER_SHAPES
    setting: str = "difficult"
    total_env_steps: int | None = None
    overrides: dict | None = None
    teacher_free: int | None = None
    config_hook: Callable[[presets.RunConfig], presets.RunConfig] | None = None

    def __post_init__(self) -> None:
        if self.seeds < 1:
            raise ConfigError(f"seeds must be >= 1, got {self.seeds}")
        for a in self.agents:
            if a not in AGENTS:
                raise ConfigError(f"agents must be among {AGENTS}, got {a!r}")
        # Normalised once here, so every derived path and plan line reads the same value.
        object.__setattr__(self, "out", Path(self.out))
        object.__setattr__(self, "agents", tuple(dict.fromkeys(self.agents)))  # start order as given, once each
        object.__setattr__(self, "shapes", tuple(self.shapes))

    @property
    def episodes_per_shape(self) -> int:
        return self.episodes or EVAL_EPISODES[self.budget]

    @property
    def report_dir(self) -> Path:
        """Where the report goes: `out`, or with `teacher_free` `out`/teacher-free (its forks' report)."""
        return self.out / TEACHER_FREE if self.teacher_free else self.out

    @property
    def budget_env_steps(self) -> int:
        """The env steps each budget run trains for (the budget's or `total_env_steps`), as the report and
        `reproduce --cpu` state it: without `config_hook`, which only tests set."""
        return budget_config(
            self.budget, "vpm", 0, self.total_env_steps, overrides=self.overrides
        ).train.loop.total_env_steps

    def runs(self) -> list[tuple[str, int]]:
        """Every (agent, seed), seed-major (so the first finished runs cover every agent)."""
        return [(agent, seed) for seed in range(self.seeds) for agent in self.agents]

    def spec(self, shape: str) -> EvalSpec:
        """The evaluation of one shape: its episodes, in batches of at most 20."""
        episodes = self.episodes_per_shape
        return EvalSpec(setting=self.setting, shape=shape, episodes=episodes, batch=min(episodes, 20))

    def config(self, agent: str, seed: int) -> presets.RunConfig:
        """The budget's run of `agent` and `seed` (`budget_config`, with this study's variants)."""
        return budget_config(self.budget, agent, seed, self.total_env_steps, self.config_hook, self.overrides)

    def run_dir(self, agent: str, seed: int) -> Path:
        """Where the budget's run of `agent` and `seed` lives."""
        return self.out / "runs" / f"{agent}-s{seed}"

    def fork_dir(self, agent: str, seed: int) -> Path:
        """Where the run's fork without the teacher lives (with `teacher_free`)."""
        return self.out / TEACHER_FREE / "runs" / f"{agent}-s{seed}"

    def job_config(self, agent: str, seed: int) -> tuple[presets.RunConfig, Path]:
        """The configuration and directory of the run the report scores for `agent` and `seed`: the
        budget's run, or with `teacher_free` its fork without the teacher."""
        cfg = self.config(agent, seed)
        if self.teacher_free:
            return teacher_free_config(cfg, self.teacher_free), self.fork_dir(agent, seed)
        return cfg, self.run_dir(agent, seed)

"""`mjx-push train`: one run of a preset, resumed or forked (`mjx_push.train.runs.run.run`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import tyro

from mjx_push.cli.options import flag_errors, set_error
from mjx_push.train.config import AgentKind
from mjx_push.train.config import Preset

from mjx_push.errors import ConfigError


def _preset_arg(metavar: str):
    # The preset decides these unless given: say so instead of tyro's "(default: None)".
    return tyro.conf.arg(metavar=metavar, help_behavior_hint="(default: the preset's)")


@dataclasses.dataclass
class Train:
    """Train a pushing agent (SAC + HER) on the MJX scene: logs, checkpoints, best policy in --run-dir.

    Presets: cpu (the default: learns to push in 8-12 minutes on 2 fast CPU cores, twice that on slow
    ones: 6 of 10 objects end within 1 cm), cpu-long (25-30 minutes on fast cores, for 1 cm),
    teacher-free (cpu-long, then the teacher annealed away and as long again on its own: the comparison's recipe), smoke (minutes, proves the pipeline), reference (the reference code's one
    call of its training script: 29,000 env steps with its action box and learner), paper (millions of
    env steps, sized for one GPU). Any option left unset keeps the preset's value. Ctrl-C (or
    SIGTERM) stops after the current batch with a checkpoint; --resume continues it. --fork-from starts
    a new run from another run's checkpoint with changed settings (e.g. the teacher annealed away)."""

    agent: Annotated[
        AgentKind | None, tyro.conf.arg(metavar="{vpm,stacked,ugru,egru}", help_behavior_hint="(default: vpm)")
    ] = None
    """vpm (the cheapest to train on a CPU), stacked, ugru, egru (the paper's proposal)"""
    preset: Annotated[
        Preset | None,
        tyro.conf.arg(metavar="{smoke,cpu,cpu-long,teacher-free,reference,paper}", help_behavior_hint="(default: cpu)"),
    ] = None
    seed: Annotated[int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: 0)")] = None
    run_dir: Annotated[
        Path | None, tyro.conf.arg(metavar="DIR", help_behavior_hint="(default: runs/<agent>-<preset>-s<seed>)")
    ] = None
    """where the run's config, logs, checkpoints and policies go"""
    resume: Annotated[bool, tyro.conf.arg(help_behavior_hint="")] = False
    """continue the run in --run-dir from its latest checkpoint (same configuration required; with a
    larger --total-env-steps, finished or not, train it longer)"""
    fork_from: Annotated[Path | None, tyro.conf.arg(metavar="RUN_DIR", help_behavior_hint="(default: none)")] = None
    """start a new run in --run-dir from this run's checkpoint: its configuration with the options and
    --set given here, its networks, optimisers and replay, env steps counted on (docs/cli.md)"""
    fork_step: Annotated[int | None, tyro.conf.arg(metavar="N", help_behavior_hint="(default: its latest)")] = None
    """with --fork-from: the checkpoint to start from, in env steps"""
    encoder: Annotated[
        Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: the shipped pretrained encoder)")
    ] = None
    """encoder weights (.msgpack, from mjx-push train-encoder)"""
    num_envs: Annotated[int | None, _preset_arg("N")] = None
    total_env_steps: Annotated[int | None, _preset_arg("N")] = None
    warmup_env_steps: Annotated[int | None, _preset_arg("N")] = None
    utd: Annotated[float | None, _preset_arg("X")] = None
    """gradient updates per environment step"""
    batch_size: Annotated[int | None, _preset_arg("N")] = None
    lr: Annotated[float | None, _preset_arg("X")] = None
    eval_every_env_steps: Annotated[int | None, _preset_arg("N")] = None
    eval_episodes: Annotated[int | None, _preset_arg("N")] = None
    data_parallel: Annotated[int | None, _preset_arg("N")] = None
    """devices to spread the run over, data parallel: each steps its share of --num-envs and holds its
    share of replay, gradients averaged over all (every device of every process when several join)"""
    coordinator: Annotated[
        str | None, tyro.conf.arg(metavar="HOST:PORT", help_behavior_hint="(default: one process)")
    ] = None
    """process 0's address, to train as one of several processes (jax.distributed; also
    MJX_PUSH_COORDINATOR); auto: JAX finds it and the two below in SLURM, Open MPI or Kubernetes
    (docs/scaling.md)"""
    num_processes: Annotated[int | None, tyro.conf.arg(metavar="N", help_behavior_hint="")] = None
    """processes in a multi-process run (also MJX_PUSH_NUM_PROCESSES)"""
    process_id: Annotated[int | None, tyro.conf.arg(metavar="I", help_behavior_hint="")] = None
    """this process's index, 0 to --num-processes - 1 (also MJX_PUSH_PROCESS_ID)"""
    checkpoint_every: int = 10
    """also checkpoint every this many episode batches (always at evaluations and at the end)"""
    success_tau: Annotated[float | None, tyro.conf.arg(metavar="METRES", help_behavior_hint="(default: 0.01)")] = None
    """success radius for the reward, success and HER relabelling (0.01 is the paper's;
    the original vision-proprioception model used 0.05)"""
    substep_chunk: Annotated[int | None, tyro.conf.arg(metavar="N", help_behavior_hint="(default: 50)")] = None
    """substeps per tick of the rollout's scheduler (0: all environments step in lockstep,
    each step waiting for the slowest); changes speed only, never the episodes"""
    progress: Annotated[bool, tyro.conf.arg(help_behavior_hint="")] = True
    """no progress bar, only a line per evaluation (output that is not a terminal,
    e.g. a log file, gets plain progress lines anyway)"""
    set: Annotated[tuple[str, ...], tyro.conf.arg(metavar="PATH=VALUE", help_behavior_hint="(default: none)")] = ()
    """override any field of the run configuration (config.json's paths; values in JSON), e.g.
    --set train.sac.bc_weight=0 env.controller.gain=1 env.substeps=[10,600]; applied after the other
    options"""

    # Options that override a field of the preset's run configuration: error messages about that field
    # name the option instead.
    _FIELDS = {
        "num_envs": "loop.num_envs",
        "total_env_steps": "loop.total_env_steps",
        "warmup_env_steps": "loop.warmup_env_steps",
        "utd": "loop.utd",
        "eval_every_env_steps": "loop.eval_every_env_steps",
        "eval_episodes": "loop.eval_episodes",
        "batch_size": "sac.batch_size",
        "lr": "sac.lr",
        "data_parallel": "loop.data_parallel",
    }

    def config(self):
        from mjx_push.train import presets

        with flag_errors(self._flag_names()):
            if self.fork_from is None:
                cfg = presets.make(self.agent or "vpm", self.preset or "cpu", self.seed or 0)
            else:  # the source's configuration, which only the options given here change
                cfg = self._fork_base()
            typed = {f"train.{field}": getattr(self, name) for name, field in self._FIELDS.items()}
            typed["env.success_tau"] = self.success_tau  # the task's, so the learner's rewards too
            cfg = presets.with_overrides(cfg, {k: v for k, v in typed.items() if v is not None})
            if self.encoder is not None:
                cfg = dataclasses.replace(cfg, encoder=str(self.encoder))
        if self.set:
            try:
                cfg = presets.with_overrides(cfg, presets.parse_overrides(self.set))
            except ValueError as e:
                raise set_error(e) from None
        return cfg

    def _fork_base(self):
        from mjx_push.train import presets
        from mjx_push.train.runs import fork

        cfg = fork.source_config(fork.ForkSource(self.fork_from))
        for flag, mine, theirs in (("--agent", self.agent, cfg.agent), ("--preset", self.preset, cfg.preset)):
            if mine is not None and mine != theirs:
                raise ConfigError(
                    f"{flag} {mine}: the run forked ({self.fork_from}) is {theirs}; a fork keeps its "
                    f"source's {flag[2:]} (drop {flag})"
                )
        return cfg if self.seed is None else presets.with_overrides(cfg, {"train.loop.seed": self.seed})

    def _default_run_dir(self) -> Path:
        if self.fork_from is not None:
            return Path(f"{self.fork_from}-fork")
        return Path("runs") / f"{self.agent or 'vpm'}-{self.preset or 'cpu'}-s{self.seed or 0}"

    def _flag_names(self) -> dict[str, str]:
        names = {field: "--" + name.replace("_", "-") for name, field in self._FIELDS.items()}
        names.update(
            {
                "env.success_tau": "--success-tau",
                "success_tau": "--success-tau",
                "substep_chunk": "--substep-chunk",
                "checkpoint_every": "--checkpoint-every",
            }
        )
        return names

    def run(self) -> None:
        from rich.console import Console

        from mjx_push.train import data_parallel
        from mjx_push.train.runs import fork
        from mjx_push.train.runs import run as run_mod
        from mjx_push.cli.progress import TrainProgress

        # Before anything starts JAX's backend: a multi-process run's devices are all its processes'.
        data_parallel.initialize(self.coordinator, self.num_processes, self.process_id)
        console = Console(quiet=not data_parallel.is_primary())  # process 0 speaks for the run
        run_dir = self.run_dir or self._default_run_dir()
        if self.checkpoint_every < 1:
            raise ConfigError(f"--checkpoint-every must be >= 1, got {self.checkpoint_every}")
        if self.fork_step is not None and self.fork_from is None:
            raise ConfigError("--fork-step N picks the checkpoint of --fork-from RUN_DIR; pass --fork-from too")
        if self.resume and self.fork_from is None:  # with --fork-from: refused by the run
            others = [n for n in self._overrides() if n != "total_env_steps"]
            if others:
                raise ConfigError(
                    "--resume continues the saved configuration (only --total-env-steps may train it "
                    f"longer); drop the other settings ({', '.join('--' + n.replace('_', '-') for n in others)})"
                )
            if not run_dir.is_dir() and self.run_dir is None:
                raise ConfigError(
                    f"--resume: no run directory {run_dir} (the default for these --agent/--preset/--seed; "
                    "pass --run-dir)"
                )
            with flag_errors(self._flag_names()):
                cfg = run_mod.resume_config(run_dir, self.total_env_steps)
        else:
            cfg = self.config()
        source = None if self.fork_from is None else fork.ForkSource(self.fork_from, self.fork_step)

        def header(start: run_mod.Start) -> None:
            """Printed once the run's rules hold (`mjx_push.train.runs.run.run` checks them)."""
            loop, T = cfg.train.loop, cfg.env.episode_length
            if self.resume and self.total_env_steps is not None:
                console.print(f"training {run_dir} to {loop.total_env_steps:,} env steps in all", soft_wrap=True)
            console.print(
                f"[bold]mjx-push train[/] {cfg.agent} ({cfg.preset}): {loop.num_envs} envs, "
                f"{loop.total_env_steps:,} env steps, {loop.warmup_env_steps:,} warm-up, "
                f"{loop.updates_per_iteration(T)} updates per batch of {loop.env_steps_per_iteration(T)} steps; "
                f"run dir {run_dir}",
                soft_wrap=True,
            )
            if start.fork_step is not None:
                console.print(
                    f"  forked from {self.fork_from} at {start.fork_step:,} env steps; changed: "
                    + (
                        "; ".join(start.fork_changes)
                        if start.fork_changes
                        else "nothing (a copy trained on with its own random numbers)"
                    ),
                    soft_wrap=True,
                )
            console.print("  the first batch includes JIT compilation (minutes on CPU)")

        try:
            with (
                TrainProgress(
                    console,
                    cfg.train.loop,
                    cfg.env.episode_length,
                    enabled=self.progress and data_parallel.is_primary(),
                ) as bar,
                flag_errors(self._flag_names()),
            ):
                summary, _ = run_mod.run(
                    cfg,
                    run_dir,
                    resume=self.resume,
                    fork=source,
                    checkpoint_every=self.checkpoint_every,
                    on_iteration=bar.update,
                    substep_chunk=self.substep_chunk,
                    stop_on_signal=True,
                    on_start=header,
                )
        except run_mod.RunFinished as done:
            console.print(f"{done} Nothing was changed.", soft_wrap=True)
            return
        if "interrupted_at_env_steps" in summary:
            console.print(
                f"[yellow]interrupted[/] ({summary['signal']}) at {summary['interrupted_at_env_steps']:,} "
                f"env steps; checkpoint written. Continue with: mjx-push train --resume --run-dir {run_dir}",
                soft_wrap=True,
            )
            raise SystemExit(130)
        console.print(
            f"best evaluation: mean reward {summary['best_eval_mean_reward']:.2f}, success "
            f"{summary['best_eval_success_rate']:.0%} at {summary['best_env_steps']:,} env steps"
        )
        console.print(
            f"policy: {run_dir / 'best_policy.msgpack'} (+ .json); logs: {run_dir / 'metrics.csv'}, "
            f"TensorBoard {run_dir / 'tb'}; checkpoints: {run_dir / 'checkpoints'}"
        )

    def _overrides(self) -> list[str]:
        names = (*self._FIELDS, "encoder", "success_tau")
        return [n for n in names if getattr(self, n) is not None] + (["set"] if self.set else [])

"""The training side's commands of `mjx-push` (train, eval, reproduce, train-encoder, demo): typed
dataclasses that tyro turns into subcommands, each with `run()`. The entry point that composes them with
the export side's commands is `export.cli.main` (the layers import one way: mjx_push -> train -> export)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import mjx_push  # noqa: F401  (applies the CPU XLA flag before jax starts)
import tyro

from train.config import AgentKind
from train.eval_options import EvalOptions
from train.flags import flag_errors
from train.presets import Preset
from mjx_push.errors import ConfigError


@dataclasses.dataclass
class Demo:
    """Step a batch of pushing scenes with random actions; show substeps/s; write a PNG of the masks."""

    num_envs: int = 16
    """environments stepped in parallel (>= 2 for mixed shapes)"""
    steps: int = 20
    """environment steps (each runs 10-600 substeps of 1 ms)"""
    seed: int = 0
    out: Path = Path("outputs/demo")
    """folder for masks.png and demo.json"""
    shape: str = "any"
    """object shape filter: any, cylinder, cuboid, square, rectangular"""

    def run(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from mjx_push import objects, throughput
        from mjx_push.env import EnvConfig

        cfg = EnvConfig(objects=objects.ObjectConfig(shape=self.shape))
        console = Console()
        console.print(
            f"[bold]mjx-push demo[/]: {self.num_envs} environments, {self.steps} random steps "
            "(the first step includes JIT compilation)"
        )
        with Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TextColumn("{task.fields[sps]}"),
            TimeElapsedColumn(),
            console=console,
        ) as bar:
            task = bar.add_task("stepping", total=self.steps, sps="compiling...")

            def progress(i, total, sps):
                bar.update(task, completed=i, sps=f"{sps:,.0f} substeps/s" if sps else "compiling...")

            stats = throughput.run(cfg, self.num_envs, self.steps, self.seed, self.out, progress)
        for k, v in stats.items():
            console.print(f"  {k}: {v}")


@dataclasses.dataclass
class TrainEncoder:
    """Train the mask autoencoder (docs/task.md section 5) on masks drawn on device; report held-out IoU.

    The shipped encoder (mjx_push/assets/encoder.msgpack) was made by this command with
    `--out mjx_push/assets/encoder.msgpack`; its JSON record holds the exact command and seed."""

    steps: int = 6000
    batch_size: int = 64
    lr: float = 1e-3
    kl_weight: float = 1.0
    yaw_weight: float = 0.0
    """weight of an auxiliary loss that makes the latent carry cuboid orientation (0: the paper's loss)"""
    eval_masks: int = 1000
    eval_every: int = 500
    seed: int = 0
    out: Path = Path("outputs/encoder/encoder.msgpack")
    """encoder weights (msgpack); a JSON record with the same stem is written next to it"""

    def run(self) -> None:
        import platform
        import time

        import jax
        from rich.console import Console

        from mjx_push import encoder as enc
        from train.encoder_training import EncoderTrainConfig, train_encoder

        cfg = EncoderTrainConfig(
            steps=self.steps,
            batch_size=self.batch_size,
            lr=self.lr,
            kl_weight=self.kl_weight,
            yaw_weight=self.yaw_weight,
            eval_masks=self.eval_masks,
            eval_every=self.eval_every,
            seed=self.seed,
        )
        console = Console()
        console.print(f"[bold]mjx-push train-encoder[/]: {cfg.steps} steps of {cfg.batch_size} fresh masks")

        def progress(step, row):
            console.print(
                f"  step {step:>6}  loss {row['loss']:8.2f}  held-out IoU {row['heldout_iou']:.4f}"
                f"  {row['seconds']:7.0f} s"
            )

        params, report = train_encoder(cfg, progress)
        record = {
            "command": (
                f"mjx-push train-encoder --steps {cfg.steps} --batch-size {cfg.batch_size} --lr {cfg.lr} "
                f"--kl-weight {cfg.kl_weight} --yaw-weight {cfg.yaw_weight} --eval-masks {cfg.eval_masks} "
                f"--seed {cfg.seed} "
                f"--out {self.out}"
            ),
            "seed": cfg.seed,
            "created": time.strftime("%Y-%m-%d %H:%M:%S"),
            "jax": jax.__version__,
            "backend": jax.default_backend(),
            "machine": platform.processor() or platform.machine(),
            **report,
        }
        enc.save(self.out, params["encoder"], record)
        console.print(
            f"held-out IoU mean {report['iou_mean']:.4f} (5th percentile {report['iou_p05']:.4f}); "
            f"encoder written to {self.out}"
        )


def _preset_arg(metavar: str):
    # The preset decides these unless given: say so instead of tyro's "(default: None)".
    return tyro.conf.arg(metavar=metavar, help_behavior_hint="(default: the preset's)")


@dataclasses.dataclass
class Train:
    """Train a pushing agent (SAC + HER) on the MJX scene: logs, checkpoints, best policy in --run-dir.

    Presets: cpu (the default: learns to push in under 10 minutes on 2 CPU cores: 6 of 10 objects end
    within 1 cm), cpu-long (25-30 minutes, for 1 cm), teacher-free (cpu-long, then the teacher annealed
    away and as long again on its own: the comparison's recipe), smoke (minutes, proves the pipeline), reference (the reference code's one
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
        from train import presets

        with flag_errors(self._flag_names()):
            if self.fork_from is None:
                cfg = presets.make(self.agent or "vpm", self.preset or "cpu", self.seed or 0)
            else:  # the source's configuration, which only the options given here change
                cfg = self._fork_base()
            typed = {f"train.{field}": getattr(self, name) for name, field in self._FIELDS.items()}
            typed["env.success_tau"] = self.success_tau  # the learner's relabelling radius follows it
            cfg = presets.with_overrides(cfg, {k: v for k, v in typed.items() if v is not None})
            if self.encoder is not None:
                cfg = dataclasses.replace(cfg, encoder=str(self.encoder))
        if self.set:
            try:
                cfg = presets.with_overrides(cfg, presets.parse_overrides(self.set))
            except ValueError as e:
                raise _set_error(e) from None
        return cfg

    def _fork_base(self):
        from train import fork, presets

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
                "replay.success_tau": "--success-tau",
                "success_tau": "--success-tau",
                "substep_chunk": "--substep-chunk",
                "checkpoint_every": "--checkpoint-every",
            }
        )
        return names

    def run(self) -> None:
        from rich.console import Console

        from train import data_parallel, fork, run as run_mod
        from train import presets
        from train.progress import TrainProgress

        # Before anything starts JAX's backend: a multi-process run's devices are all its processes'.
        data_parallel.initialize(self.coordinator, self.num_processes, self.process_id)
        console = Console(quiet=not data_parallel.is_primary())  # process 0 speaks for the run
        run_dir = self.run_dir or self._default_run_dir()
        if self.checkpoint_every < 1:
            raise ConfigError(f"--checkpoint-every must be >= 1, got {self.checkpoint_every}")
        if self.fork_step is not None and self.fork_from is None:
            raise ConfigError("--fork-step N picks the checkpoint of --fork-from RUN_DIR; pass --fork-from too")
        if self.resume and self.fork_from is not None:
            raise ConfigError(
                "--resume continues the run in --run-dir; --fork-from starts a new one: pass one of them "
                "(an interrupted fork continues with --resume alone)"
            )
        if self.resume:
            if not run_dir.is_dir():
                raise ConfigError(
                    f"--resume: no run directory {run_dir}"
                    + ("" if self.run_dir else " (the default for these --agent/--preset/--seed; pass --run-dir)")
                )
            cfg = presets.load_config(run_dir / "config.json")
            others = [n for n in self._overrides() if n != "total_env_steps"]
            if others:
                raise ConfigError(
                    "--resume continues the saved configuration (only --total-env-steps may train it "
                    f"longer); drop the other settings ({', '.join('--' + n.replace('_', '-') for n in others)})"
                )
            if self.total_env_steps is not None and self.total_env_steps != cfg.train.loop.total_env_steps:
                if self.total_env_steps < cfg.train.loop.total_env_steps:
                    raise ConfigError(
                        f"--total-env-steps {self.total_env_steps:,} with --resume: the run in {run_dir} "
                        f"trains for {cfg.train.loop.total_env_steps:,} env steps; --resume can train it "
                        "longer, not shorter"
                    )
                with flag_errors(self._flag_names()):
                    cfg = presets.with_overrides(cfg, {"train.loop.total_env_steps": self.total_env_steps})
                console.print(f"training {run_dir} longer: {self.total_env_steps:,} env steps in all", soft_wrap=True)
            try:
                run_mod.check_not_finished(run_dir, cfg)
            except run_mod.RunFinished as done:
                console.print(f"{done} Nothing was changed.", soft_wrap=True)
                return
        else:
            cfg = self.config()
        source = None if self.fork_from is None else fork.ForkSource(self.fork_from, self.fork_step)
        if source is not None:  # refused before anything is printed as started
            step, changes = fork.check_fork(source, cfg)
        loop = cfg.train.loop
        console.print(
            f"[bold]mjx-push train[/] {cfg.agent} ({cfg.preset}): {loop.num_envs} envs, "
            f"{loop.total_env_steps:,} env steps, {loop.warmup_env_steps:,} warm-up, "
            f"{loop.updates_per_iteration} updates per batch of {loop.env_steps_per_iteration} steps; "
            f"run dir {run_dir}",
            soft_wrap=True,
        )
        if source is not None:
            console.print(
                f"  forked from {self.fork_from} at {step:,} env steps; changed: "
                + ("; ".join(changes) if changes else "nothing (a copy trained on with its own random numbers)"),
                soft_wrap=True,
            )
        console.print("  the first batch includes JIT compilation (minutes on CPU)")
        try:
            with (
                TrainProgress(console, loop, enabled=self.progress and data_parallel.is_primary()) as bar,
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


def resolve_policy(path: Path, name: str = "POLICY"):
    """A run directory (its best policy) or a saved policy (.msgpack/.json or their stem) ->
    train.policies.Policy (exported files are the export side's: `export.cli.Eval`). Errors name the option
    (`name`) and the path as the user typed it."""
    from train import policies

    path = Path(path)
    stem = path.with_suffix("") if path.suffix in (".msgpack", ".json") else path
    if not (path.exists() or stem.with_suffix(".msgpack").exists() or stem.with_suffix(".json").exists()):
        raise ConfigError(
            f"{name} {path}: no such file or directory (a run directory, a saved policy "
            "best_policy.msgpack / .json or their stem, or an exported .npz)"
        )
    try:
        if path.is_dir():
            if (path / "best_policy.msgpack").is_file():
                return policies.load_policy(path / "best_policy")
            raise ConfigError("not a finished run directory (no best_policy.msgpack)")
        return policies.load_policy(path)
    except ValueError as e:
        raise ConfigError(f"{name} {path}: {e}") from None


@dataclasses.dataclass(kw_only=True)
class Eval(EvalOptions):
    """Evaluate a policy with the paper's protocol (docs/task.md section 7) on the MJX scene.
    `mjx-push deploy` runs an exported policy through the same protocol in CPU MuJoCo: the same options,
    defaults, episodes and table."""

    policy: Annotated[Path, tyro.conf.arg(metavar="POLICY"), tyro.conf.Positional]
    """a run directory, a saved policy (best_policy.msgpack), an exported .npz, a shipped policy
    (`pretrained:NAME`), or `expert`: the scripted expert on ground truth (a baseline, not a deployable
    policy)"""
    batch: int = 20
    """episodes simulated in parallel (does not change the episodes)"""
    success_tau: Annotated[
        float | None, tyro.conf.arg(metavar="M", help_behavior_hint=("(default: the radius the policy trained for)"))
    ] = None
    """success radius in metres to score at (the correction counters use it too)"""
    preset: Annotated[
        Preset | None,
        tyro.conf.arg(metavar="{cpu,cpu-long,teacher-free,smoke,reference,paper}", help_behavior_hint="(default: cpu)"),
    ] = None
    """POLICY expert only: the preset whose action box the expert acts in (reference: the paper's)"""
    out: Annotated[
        Path | None,
        tyro.conf.arg(
            metavar="PATH",
            help_behavior_hint="(default: eval.json beside the policy; outputs/eval-expert.json for the expert)",
        ),
    ] = None
    """JSON with the table and per-episode values"""

    def resolve(self, path: Path):
        """POLICY -> train.policies.Policy (the export side's command adds exported and shipped files)."""
        return resolve_policy(path)

    def run(self) -> None:
        record, out, res = self.evaluate()
        self.write(record, out)
        self.write_video(res)

    def evaluate(self) -> tuple[dict, Path, dict]:
        """Check the options, evaluate in MJX and print the table: (the JSON record, where it goes, the
        evaluation's full result)."""
        import numpy as np
        from rich.console import Console

        from train.evaluate import evaluate, metrics_table

        if self.batch < 1:
            raise ConfigError(f"--batch must be a positive integer, got {self.batch}")
        if self.success_tau is not None and not self.success_tau > 0:
            raise ConfigError(f"--success-tau must be a positive number of metres, got {self.success_tau}")
        is_expert = str(self.policy) == "expert"
        if self.preset is not None and not is_expert:
            raise ConfigError("--preset chooses the scripted expert's action box: use it with POLICY expert")
        self.check_options()
        spec = dataclasses.replace(self.spec(self.batch), success_tau=self.success_tau)
        if is_expert:
            from train import presets
            from train.evaluate import ExpertPolicy

            policy = ExpertPolicy(presets.make("vpm", self.preset or "cpu"))
        else:
            policy = self.resolve(self.policy)
        console = Console()
        name = f"expert ({self.preset or 'cpu'} action box)" if is_expert else policy.config.agent
        tau = spec.success_tau or policy.config.env.success_tau
        console.print(
            f"[bold]mjx-push eval[/] {name} (JAX, MJX): {self.policy}, {spec.episodes} "
            f"episodes, setting {spec.setting}, shape {spec.shape}, success within {100 * tau:g} cm "
            "(the first batch includes JIT compilation)"
        )
        res = evaluate(policy, spec)
        s = res["summary"]
        console.print(
            metrics_table(
                f"{name} / {spec.setting} / {spec.shape} ({spec.episodes} "
                f"episodes, MJX, success within {100 * tau:g} cm)",
                s,
            )
        )
        if res["invalid_episodes"]:
            console.print(
                f"[yellow]{res['invalid_episodes']} episodes hit an invalid simulation state "
                f"(counted as failures with reward -{policy.config.env.episode_length})"
            )
        out = self.out or (
            Path("outputs/eval-expert.json")
            if is_expert
            else (self.policy if self.policy.is_dir() else self.policy.parent) / "eval.json"
        )
        record = {
            "policy": str(self.policy),
            "agent": name,
            "spec": dataclasses.asdict(spec),
            "summary": s,
            "invalid_episodes": res["invalid_episodes"],
            "per_episode": {k: np.asarray(v).tolist() for k, v in res["per_episode"].items()},
        }
        return record, out, res

    def write(self, record: dict, out: Path) -> None:
        import json

        from rich.console import Console

        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(record, indent=2) + "\n")
        Console().print(f"written {out}")

    def write_video(self, res: dict) -> None:
        if self.video is None:
            return
        from rich.console import Console

        from mjx_push import video

        r = video.EpisodeRenderer()
        frames = []
        for ep in res["recorded"]:
            p = ep["params"]
            frames += r.frames(ep["geom_type"], p.size, p.goal, ep["qpos"])
        r.close()
        Console().print(f"video: {video.write(frames, self.video)} ({len(frames)} frames)")


def _set_error(e: ValueError) -> ConfigError:
    """A refused `--set` (train's and reproduce's): unknown paths name themselves; a bad value names its field."""
    return ConfigError(str(e) if str(e).startswith("--set") else f"--set: {e}")


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

    def overrides(self) -> dict:
        """`--set` as {path: value}, checked against the budget's configuration of every agent asked for."""
        from train import presets
        from train import reproduce as rep

        try:
            overrides = presets.parse_overrides(self.set)
            for agent in self.agents:
                rep.budget_config(self.budget, agent, 0, overrides=overrides)
        except ValueError as e:
            raise _set_error(e) from None
        return overrides

    def run(self) -> None:
        from rich.console import Console

        from train import reproduce as rep

        console = Console()
        out = self.out or Path(f"outputs/reproduce-{self.budget}")
        if self.episodes is not None and self.episodes < 1:
            raise ConfigError(f"--episodes must be >= 1, got {self.episodes}")
        if self.jobs < 1:
            raise ConfigError(f"--jobs must be >= 1, got {self.jobs}")
        if self.seeds < 1:
            raise ConfigError(f"--seeds must be >= 1, got {self.seeds}")
        if self.total_env_steps is not None:
            with flag_errors({"loop.total_env_steps": "--total-env-steps"}):
                rep.budget_config(self.budget, "vpm", 0, self.total_env_steps)  # refused here, not in a job
        overrides = self.overrides()
        if self.teacher_free is not None:
            for agent in self.agents:  # refused here, not in a job
                rep.teacher_free_config(
                    rep.budget_config(self.budget, agent, 0, self.total_env_steps, overrides=overrides),
                    self.teacher_free,
                )
        if sum(x is not None and x is not False for x in (self.plan, self.job, self.report_only or None)) > 1:
            raise ConfigError("--plan, --job and --report-only exclude each other")
        if self.plan is not None:
            lines = rep.plan(
                self.budget,
                self.seeds,
                out,
                tuple(self.agents),
                self.episodes,
                self.total_env_steps,
                overrides,
                self.teacher_free,
            )
            self.plan.parent.mkdir(parents=True, exist_ok=True)
            self.plan.write_text("\n".join(lines) + "\n")
            console.print(f"{len(lines)} commands written to {self.plan}:", *lines, sep="\n", markup=False)
            return
        episodes = self.episodes or rep.EVAL_EPISODES[self.budget]
        if self.job is not None:
            if self.job == "expert":
                rep.expert_job(
                    self.budget, out, episodes, rep.PAPER_SHAPES, "difficult", log=console.print, overrides=overrides
                )
                return
            agent, sep, seed = self.job.partition(":")
            if not sep or agent not in rep.AGENTS or not seed.isdigit():
                raise ConfigError(
                    f"--job must be AGENT:SEED (AGENT one of {rep.AGENTS}, SEED an int >= 0) or "
                    f"'expert', got {self.job!r}"
                )
            rep.agent_job(
                self.budget,
                agent,
                int(seed),
                out,
                episodes,
                rep.PAPER_SHAPES,
                "difficult",
                log=console.print,
                total_env_steps=self.total_env_steps,
                overrides=overrides,
                teacher_free=self.teacher_free,
            )
            return
        path = rep.reproduce(
            self.budget,
            self.seeds,
            out,
            self.episodes,
            tuple(self.agents),
            log=console.print,
            jobs=self.jobs,
            report_only=self.report_only,
            total_env_steps=self.total_env_steps,
            overrides=overrides,
            teacher_free=self.teacher_free,
        )
        console.print(f"report: {path}")
        console.print((path.parent / "report.md").read_text(), markup=False, soft_wrap=True)  # verbatim Markdown


@dataclasses.dataclass
class Protocol:
    """Run a pre-registered comparison: every agent x seed of FOLDER/protocol.json trained at its preset
    and scored on its test episodes, each run recorded in FOLDER/runs/ as it ends (a failed run too),
    the scripted expert in FOLDER/expert.json; then `python -m train.comparison_tables FOLDER` prints the
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

        from train import protocol as proto
        from train.comparison_tables import DataError

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
            lines = proto.plan(runs)
            self.plan.parent.mkdir(parents=True, exist_ok=True)
            self.plan.write_text("\n".join(lines) + "\n")
            console.print(f"{len(lines)} commands written to {self.plan}:", *lines, sep="\n", markup=False)
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


# The training side's subcommands (`export.cli.main` adds the export side's and runs them).
COMMANDS = {
    "train": Train,
    "eval": Eval,
    "reproduce": Reproduce,
    "protocol": Protocol,
    "train-encoder": TrainEncoder,
    "demo": Demo,
}

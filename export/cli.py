"""The `mjx-push` command line: `main` composes the training side's commands (`train.cli.COMMANDS`)
with the export side's, `mjx-push export` and `mjx-push deploy` (tyro dataclass commands, each with
`run()`), and `mjx-push eval` learns to read exported and shipped policies here. It sits in the last
layer because it composes all three (mjx_push -> train -> export)."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Annotated, Literal

import tyro

from train import cli as train_cli
from train.eval_options import EvalOptions
from train.provenance import source_commit
from mjx_push.errors import ConfigError

VIDEO_FPS = 5  # one frame per environment step


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

        from export.policy_file import FORMAT, FORMAT_VERSION, export_policy
        from train.policies import load_policy

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


@dataclasses.dataclass(kw_only=True)
class Deploy(EvalOptions):
    """Run an exported policy (.npz, pure NumPy) in CPU MuJoCo with the evaluation protocol of `mjx-push
    eval` (docs/task.md section 7): the same settings, shapes, defaults and episodes, the same table."""

    policy: Annotated[Path, tyro.conf.arg(metavar="POLICY.npz"), tyro.conf.Positional]
    """the exported .npz (from `mjx-push export`), or a shipped policy: `pretrained:NAME`"""
    sim: Literal["cpu"] = "cpu"
    """simulator: CPU MuJoCo (export.cpu_env.CpuPushEnv)"""
    mask_source: Literal["auto", "render", "analytic"] = "auto"
    """object masks: the rendered under-table camera, the analytic projection (as in MJX),
    or render when possible (the header says which)"""
    out: Annotated[
        Path | None, tyro.conf.arg(aliases=("--out-json",), metavar="PATH", help_behavior_hint="(default: none)")
    ] = None
    """write the per-episode records and the summary here (JSON)"""

    def _check(self) -> None:
        from export.cpu_env import MASK_SOURCES

        if self.sim != "cpu":
            raise ConfigError(f"--sim must be 'cpu', got {self.sim!r}")
        if self.mask_source not in MASK_SOURCES:
            raise ConfigError(f"--mask-source must be one of {MASK_SOURCES}, got {self.mask_source!r}")
        from export.pretrained import resolve

        self.policy = resolve(self.policy)
        if Path(self.policy).suffix != ".npz":
            raise ConfigError(f"POLICY.npz must be an exported .npz (mjx-push export makes one), got {self.policy}")
        if not Path(self.policy).is_file():
            raise ConfigError(f"POLICY.npz {self.policy}: no such file")
        self.check_options()

    def run(self) -> dict:
        self._check()
        from rich.console import Console

        from export import sim_eval
        from export.cpu_env import CpuPushEnv
        from export.metrics import summarize_records
        from export.numpy_policy import NumpyPolicy
        from train.evaluate import metrics_table

        try:
            policy = NumpyPolicy.from_file(self.policy)
        except ValueError as e:
            raise ConfigError(f"POLICY.npz {self.policy}: {e}") from None
        spec = self.spec()
        config = sim_eval.env_config(policy.metadata, spec)
        console = Console()
        writer = _open_video(Path(self.video)) if self.video is not None else None
        env = CpuPushEnv(config, mask_source=self.mask_source)

        def on_frame(episode: int, e) -> None:
            if episode < self.video_episodes:
                writer.append_data(sim_eval.side_by_side(e))

        console.print(
            f"[bold]mjx-push deploy[/] {policy.kind} (NumPy, CPU MuJoCo): {self.policy}, {self.episodes} "
            f"episodes, setting {self.setting}, shape {self.shape}, masks {env.mask_source_used}"
        )
        try:
            records = sim_eval.run_episodes(policy, env, spec, on_frame if writer is not None else None)
        finally:
            if writer is not None:
                writer.close()
            env.close()
        summary = summarize_records(records)
        invalid = sum(not r["valid"] for r in records)
        result = {
            "policy": str(self.policy),
            "agent": policy.kind,
            "setting": self.setting,
            "shape": self.shape,
            "seed": self.seed,
            "mask_source": env.mask_source_used,
            "summary": summary,
            "invalid_episodes": invalid,
            "episodes": records,
        }
        console.print(
            metrics_table(
                f"{policy.kind} / {self.setting} / {self.shape} ({self.episodes} episodes, "
                f"CPU MuJoCo, {env.mask_source_used} masks)",
                summary,
            )
        )
        if invalid:
            console.print(
                f"[yellow]{invalid} episodes hit an invalid simulation state "
                f"(counted as failures with reward -{config.episode_length})"
            )
        if self.video is not None:
            console.print(f"video: {self.video} (first {min(self.video_episodes, self.episodes)} episode(s))")
        if self.out is not None:
            Path(self.out).parent.mkdir(parents=True, exist_ok=True)
            Path(self.out).write_text(json.dumps(result, indent=2) + "\n")
            console.print(f"written {self.out}")
        return result


def _open_video(path: Path):
    import imageio.v2 as iio

    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        return iio.get_writer(path, mode="I", duration=1000 / VIDEO_FPS, loop=0)
    try:
        return iio.get_writer(path, fps=VIDEO_FPS)
    except (ValueError, ImportError, RuntimeError) as e:
        raise ConfigError(
            f"--video: no .mp4 writer is available ({str(e).splitlines()[0]}); pip install "
            f"'mjx-push[mp4]', or write a GIF: --video {path.with_suffix('.gif')}"
        ) from None


# `--cpu render analytic` of eval and reproduce: the mask sources of a CPU MuJoCo run beside the MJX one.
CpuMasks = Annotated[
    tuple[Literal["render", "analytic"], ...],
    tyro.conf.arg(metavar="{render,analytic} ...", help_behavior_hint="(default: MJX only)"),
]


def _check_cpu(sources: tuple[str, ...]) -> None:
    if len(set(sources)) != len(sources):
        raise ConfigError(f"--cpu lists a mask source twice: {' '.join(sources)}")
    if "render" in sources:
        from mjx_push.renderer import renderer_available, unavailable_reason

        if not renderer_available():
            raise ConfigError(f"--cpu render: {unavailable_reason()}; or --cpu analytic")


@dataclasses.dataclass
class Reproduce(train_cli.Reproduce):
    __doc__ = train_cli.Reproduce.__doc__

    cpu: CpuMasks = ()
    """also evaluate every finished agent and seed in CPU MuJoCo (its NumPy port) on the same episodes
    with these mask sources, and write OUT/report-parity.md: both simulators' success side by side,
    per-episode agreement, correlation of final distances (cached next to each run)"""

    def run(self) -> None:
        if self.cpu:
            if self.plan is not None or self.job == "expert":
                raise ConfigError("--cpu evaluates trained agents: not with --plan or --job expert")
            _check_cpu(self.cpu)
        super().run()
        if not self.cpu:
            return
        from rich.console import Console

        from export.report_parity import parity_report
        from train import reproduce as rep

        if self.job is not None:
            agent, _, seed = self.job.partition(":")
            runs = [(agent, int(seed))]
        else:
            runs = [(a, s) for s in range(self.seeds) for a in self.agents]
        out = self.out or Path(f"outputs/reproduce-{self.budget}")
        episodes = self.episodes or rep.EVAL_EPISODES[self.budget]
        console = Console()
        total = rep.budget_config(
            self.budget, "vpm", 0, self.total_env_steps, overrides=self.overrides()
        ).train.loop.total_env_steps
        path = parity_report(
            out, runs, rep.PAPER_SHAPES, "difficult", episodes, tuple(self.cpu), console.print, total_env_steps=total
        )
        console.print(path.read_text(), markup=False, soft_wrap=True)


def _agreement_line(group: str, a: dict) -> str:
    corr = "-" if a["final_distance_correlation"] is None else f"{a['final_distance_correlation']:.2f}"
    return (
        f"{group} {a['mjx_success']:.0%} / {a['cpu_success']:.0%} within the radius, same outcome in "
        f"{a['success_agreement']:.0%}, final distances r = {corr}"
    )


COMMANDS = {"export": Export, "deploy": Deploy}


@dataclasses.dataclass(kw_only=True)
class Eval(train_cli.Eval):
    __doc__ = train_cli.Eval.__doc__

    cpu: CpuMasks = ()
    """also run the same episodes in CPU MuJoCo (the deploy path: the NumPy policy) with these mask
    sources, and report, beside each simulator's table, how often their outcomes agree episode by
    episode and how their final distances correlate (docs/parity.md)"""

    def run(self) -> None:
        if not self.cpu:
            return super().run()
        if str(self.policy) == "expert":
            raise ConfigError("--cpu runs a trained policy's NumPy port: the scripted expert has none")
        _check_cpu(self.cpu)
        record, out, res = self.evaluate()
        record["cpu"] = self._cpu_runs(record)
        self.write(record, out)
        self.write_video(res)

    def _cpu_runs(self, record: dict) -> dict:
        """Each mask source's CPU MuJoCo run of the evaluation's episodes: its summary, its records and
        its agreement with the MJX run (`export.metrics.agreement_by_shape`)."""
        from rich.console import Console

        from export import pretrained, sim_eval
        from export.metrics import agreement_by_shape, summarize_records
        from export.numpy_policy import NumpyPolicy
        from train.evaluate import metrics_table

        console = Console()
        spec = self.spec(self.batch)
        path = pretrained.resolve(self.policy)
        if path.suffix == ".npz":
            policy = NumpyPolicy.from_file(path)
        else:  # a run directory or saved policy: its NumPy port
            policy = NumpyPolicy.from_policy(self.resolve(self.policy), {"source": str(self.policy)})
        runs = {}
        for source in self.cpu:
            records = sim_eval.run_cpu(policy, spec, source, self.success_tau)
            summary = summarize_records(records)
            agree = agreement_by_shape(record["per_episode"], records)
            console.print(
                metrics_table(f"{policy.kind} / {spec.setting} / {spec.shape} (CPU MuJoCo, {source} masks)", summary)
            )
            console.print(
                "MJX vs CPU MuJoCo ("
                + source
                + " masks): "
                + "; ".join(_agreement_line(g, a) for g, a in agree.items())
            )
            runs[source] = {"summary": summary, "agreement": agree, "episodes": records}
        return runs

    def resolve(self, path: Path):
        """Also an exported .npz and a shipped policy (`pretrained:NAME`)."""
        from export import pretrained
        from export.policy_file import load_as_policy

        path = pretrained.resolve(path)
        if path.suffix != ".npz" or not path.is_file():  # the training side's policies and its errors
            return super().resolve(path)
        try:
            return load_as_policy(path)
        except ValueError as e:
            raise ConfigError(f"POLICY {path}: {e}") from None


def main(argv: list[str] | None = None) -> int:
    """The `mjx-push` entry point."""
    commands = {**train_cli.COMMANDS, "eval": Eval, "reproduce": Reproduce, **COMMANDS}
    from mjx_push import xla
    from train import compile_cache

    xla.use_cpu_devices()  # one CPU device per core, before anything starts JAX; spawned jobs inherit it

    compile_cache.enable()
    try:
        # Boolean options are single flags (--resume, --no-progress), not --x / --no-x pairs.
        cmd = tyro.extras.subcommand_cli_from_dict(
            commands, args=argv, prog="mjx-push", config=(tyro.conf.FlagCreatePairsOff,)
        )
        cmd.run()
    except ConfigError as e:  # the user's input is wrong and the message says how: no traceback
        print(f"mjx-push: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`mjx-push deploy`: an exported policy in CPU MuJoCo on the evaluation protocol (`mjx_push.export.sim_eval`)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Annotated, Literal

import tyro

from mjx_push.cli.options import EvalOptions, flag_errors, open_video

from mjx_push.errors import ConfigError


@dataclasses.dataclass(kw_only=True)
class Deploy(EvalOptions):
    """Run an exported policy (.npz, pure NumPy) in CPU MuJoCo with the evaluation protocol of `mjx-push
    eval` (docs/task.md section 7): the same settings, shapes, defaults and episodes, the same table."""

    policy: Annotated[Path, tyro.conf.arg(metavar="POLICY.npz"), tyro.conf.Positional]
    """the exported .npz (from `mjx-push export`), or a shipped policy: `pretrained:NAME`"""
    sim: Literal["cpu"] = "cpu"
    """simulator: CPU MuJoCo (mjx_push.export.cpu_env.CpuPushEnv)"""
    perturb: Annotated[tuple[str, ...], tyro.conf.arg(metavar="NAME ...", help_behavior_hint="(default: none)")] = ()
    """run the episodes under these rows of the stress suite (docs/robustness.md: camera, latency,
    mask_flip, ...), all at once, at --perturb-level: the simulated cell as a real one would be"""
    perturb_level: Literal["mild", "realistic", "severe"] = "realistic"
    mask_source: Literal["auto", "render", "analytic"] = "auto"
    """object masks: the rendered under-table camera, the analytic projection (as in MJX),
    or render when possible (the header says which)"""
    out: Annotated[
        Path | None, tyro.conf.arg(aliases=("--out-json",), metavar="PATH", help_behavior_hint="(default: none)")
    ] = None
    """write the per-episode records and the summary here (JSON)"""

    def _check(self) -> None:
        from mjx_push.export.cpu_env import MASK_SOURCES

        if self.sim != "cpu":
            raise ConfigError(f"--sim must be 'cpu', got {self.sim!r}")
        if self.mask_source not in MASK_SOURCES:
            raise ConfigError(f"--mask-source must be one of {MASK_SOURCES}, got {self.mask_source!r}")
        from mjx_push.export.pretrained import resolve

        self.policy = resolve(self.policy)
        if Path(self.policy).suffix != ".npz":
            raise ConfigError(f"POLICY.npz must be an exported .npz (mjx-push export makes one), got {self.policy}")
        if not Path(self.policy).is_file():
            raise ConfigError(f"POLICY.npz {self.policy}: no such file")
        self.check_options()
        self._perturbations()  # refused before any work

    def _perturbations(self):
        """The stress suite's rows of --perturb at --perturb-level (None: a clean cell)."""
        if not self.perturb:
            return None
        from mjx_push import perturb

        with flag_errors({"perturbation": "--perturb", "level": "--perturb-level"}):
            return perturb.suite_config(self.perturb, self.perturb_level)

    def run(self) -> dict:
        self._check()
        from rich.console import Console

        from mjx_push.export import sim_eval
        from mjx_push.export.cpu_env import CpuPushEnv
        from mjx_push.export.metrics import summarize_records
        from mjx_push.export.numpy_policy import NumpyPolicy
        from mjx_push.train.evaluate import metrics_table

        try:
            policy = NumpyPolicy.from_file(self.policy)
        except ValueError as e:
            raise ConfigError(f"POLICY.npz {self.policy}: {e}") from None
        spec = self.spec()
        config = sim_eval.env_config(policy.metadata, spec, self._perturbations())
        console = Console()
        writer = open_video(Path(self.video)) if self.video is not None else None
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
            "perturb": {"rows": list(self.perturb), "level": self.perturb_level} if self.perturb else None,
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

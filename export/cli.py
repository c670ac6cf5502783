"""`mjx-push export` and `mjx-push deploy`: tyro dataclass commands, each with `run()` (registered by
`train.cli.main` from `COMMANDS`)."""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from pathlib import Path
from typing import Literal

import tyro

VIDEO_FPS = 5  # one frame per environment step


@dataclasses.dataclass
class Export:
    """Export a trained policy to one .npz of float32 weights + JSON metadata (for NumPy / torch / a robot)."""

    source: tyro.conf.Positional[Path]
    """a run directory (its best_policy is exported) or a saved policy (.msgpack, .json or their stem)"""
    out: tyro.conf.Positional[Path]
    """the .npz to write"""

    def run(self) -> dict:
        from rich.console import Console

        from export.policy_file import FORMAT, FORMAT_VERSION, export_policy
        from train.run import load_policy

        source = Path(self.source)
        if source.is_dir():
            stem = source / "best_policy"
            if not stem.with_suffix(".msgpack").is_file():
                raise ValueError(f"source: run directory {source} has no best_policy.msgpack (has the run finished?)")
        else:
            stem = source
        if Path(self.out).suffix != ".npz":
            raise ValueError(f"out must be an .npz path, got {self.out}")
        try:
            policy = load_policy(stem)
        except ValueError as e:
            raise ValueError(f"source: {e}") from None
        meta = export_policy(policy, self.out)
        size = Path(self.out).stat().st_size
        Console().print(f"wrote [bold]{self.out}[/] ({size / 1e6:.2f} MB): agent {meta['agent']['kind']}, "
                        f"format {FORMAT} version {FORMAT_VERSION}, from {stem}; scores {meta['scores']}")
        return meta


@dataclasses.dataclass
class Deploy:
    """Run an exported policy (.npz, pure NumPy) in CPU MuJoCo and report the SPEC section 7 metrics."""

    policy: tyro.conf.Positional[Path]
    """the exported .npz (from `mjx-push export`)"""
    sim: Literal["cpu"] = "cpu"
    """simulator: CPU MuJoCo (export.cpu_env.CpuPushEnv)"""
    episodes: int = 10
    seed: int = 0
    """episode i uses seed + i: the same objects for every policy"""
    setting: Literal["standard", "difficult"] = "standard"
    """standard: Table I objects; difficult: mass U[0.001, 0.01], friction U[0.2, 0.3], min height 0.052"""
    shape: Literal["all", "any", "cylinder", "square", "rectangular", "cuboid"] = "all"
    mask_source: Literal["auto", "render", "analytic"] = "auto"
    """object masks: rendered under-table camera, the analytic projection, or render when possible"""
    video: Path | None = None
    """write the top and under-table views side by side (.mp4 needs imageio-ffmpeg; .gif always works)"""
    video_episodes: int = 2
    """how many of the first episodes go into the video"""
    out_json: Path | None = None
    """write the per-episode records and the summary here"""

    def _check(self) -> None:
        from export import sim_eval
        from export.cpu_env import MASK_SOURCES
        from mjx_push import objects

        if self.sim != "cpu":
            raise ValueError(f"sim must be 'cpu', got {self.sim!r}")
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes <= 0:
            raise ValueError(f"episodes must be a positive integer, got {self.episodes!r}")
        if self.setting not in sim_eval.SETTINGS:
            raise ValueError(f"setting must be one of {sim_eval.SETTINGS}, got {self.setting!r}")
        if self.shape == "all":  # `mjx-push eval`'s name for the mixed setting
            self.shape = "any"
        if self.shape not in objects.SHAPE_FILTERS:
            raise ValueError(f"shape must be one of {objects.SHAPE_FILTERS}, got {self.shape!r}")
        if self.mask_source not in MASK_SOURCES:
            raise ValueError(f"mask_source must be one of {MASK_SOURCES}, got {self.mask_source!r}")
        if self.video is not None:
            if Path(self.video).suffix.lower() not in (".mp4", ".gif"):
                raise ValueError(f"video must end with .mp4 or .gif, got {self.video}")
            if not isinstance(self.video_episodes, int) or self.video_episodes <= 0:
                raise ValueError(f"video_episodes must be a positive integer, got {self.video_episodes!r}")

    def run(self) -> dict:
        if sys.platform.startswith("linux") and "DISPLAY" not in os.environ and "mujoco" not in sys.modules:
            os.environ.setdefault("MUJOCO_GL", "egl")  # headless Linux: MuJoCo's offscreen renderer needs EGL
        self._check()
        from rich.console import Console

        from export import sim_eval
        from export.cpu_env import CpuPushEnv, renderer_available
        from export.metrics import summarize
        from export.numpy_policy import NumpyPolicy

        try:
            policy = NumpyPolicy.from_file(self.policy)
        except ValueError as e:
            raise ValueError(f"policy: {e}") from None
        config = sim_eval.env_config(policy.metadata, self.setting, self.shape)
        console = Console()
        writer = None
        if self.video is not None:
            if not renderer_available():
                raise ValueError("video: MuJoCo's offscreen renderer is unavailable (set MUJOCO_GL=egl on a "
                                 "machine without a display)")
            writer = _open_video(Path(self.video))
        env = CpuPushEnv(config, mask_source=self.mask_source, seed=self.seed)

        def on_frame(episode: int, e) -> None:
            if writer is not None and episode < self.video_episodes:
                writer.append_data(sim_eval.side_by_side(e))

        console.print(f"[bold]mjx-push deploy[/]: {policy.kind} policy {self.policy}, {self.episodes} episodes, "
                      f"setting {self.setting}, shape {self.shape}, masks {env.mask_source_used}")
        try:
            records = sim_eval.run_episodes(policy, env, self.episodes, self.seed,
                                            on_frame if writer is not None else None)
        finally:
            if writer is not None:
                writer.close()
            env.close()
        summary = summarize(records)
        result = {
            "policy": str(self.policy),
            "agent": policy.kind,
            "setting": self.setting,
            "shape": self.shape,
            "seed": self.seed,
            "mask_source": env.mask_source_used,
            "summary": summary,
            "invalid_episodes": sum(not r["valid"] for r in records),
            "episodes": records,
        }
        console.print(_table(result))
        if self.video is not None:
            console.print(f"video: {self.video} (first {min(self.video_episodes, self.episodes)} episode(s))")
        if self.out_json is not None:
            Path(self.out_json).parent.mkdir(parents=True, exist_ok=True)
            Path(self.out_json).write_text(json.dumps(result, indent=2) + "\n")
            console.print(f"wrote {self.out_json}")
        return result


def _open_video(path: Path):
    import imageio.v2 as iio

    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        return iio.get_writer(path, mode="I", duration=1000 / VIDEO_FPS, loop=0)
    try:
        return iio.get_writer(path, fps=VIDEO_FPS)
    except (ValueError, ImportError, RuntimeError) as e:
        raise ValueError(f"video: no .mp4 writer is available ({str(e).splitlines()[0]}); install one with "
                         f"`pip install imageio-ffmpeg`, or write a GIF: --video {path.with_suffix('.gif')}") from None


def _table(result: dict):
    from rich.table import Table

    t = Table(title=f"{result['agent']} | {result['setting']} | shape {result['shape']} | "
                    f"masks {result['mask_source']}")
    t.add_column("metric")
    t.add_column("mean", justify="right")
    t.add_column("± SEM", justify="right")
    t.add_column("n", justify="right")
    labels = {"success_rate": "success rate", "mean_reward": "mean episode reward",
              "overshoot": "overshoot corrections", "distance": "distance corrections"}
    for key, label in labels.items():
        m = result["summary"][key]
        t.add_row(label, f"{m['mean']:.3f}", f"{m['sem']:.3f}", str(m["n"]))
    return t


COMMANDS = {"export": Export, "deploy": Deploy}

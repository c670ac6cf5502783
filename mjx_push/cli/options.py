"""What several commands share: the evaluation options of `mjx-push eval` (the MJX scene) and `mjx-push
deploy` (CPU MuJoCo), the same names, choices, defaults and checks, so both draw the same episodes
(episode i's object, start and goal come from the seed and i alone) and print the same table
(`mjx_push.train.evaluate.metrics_table`); error messages in the user's words (`flag_errors`); reading
a POLICY argument; `--cpu`'s mask sources; video files."""

from __future__ import annotations

import contextlib
import dataclasses
import re
from pathlib import Path
from typing import Annotated, Literal

import tyro

from mjx_push.errors import ConfigError


@contextlib.contextmanager
def flag_errors(names: dict[str, str]):
    """Re-raise a ValueError raised inside the block with each field of `names` (field -> option) replaced
    by its option. Other exceptions, and messages that name none of the fields, pass unchanged."""
    try:
        yield
    except ValueError as e:
        msg = str(e)
        for field in sorted(names, key=len, reverse=True):
            # A field matches whole, optionally under the run config's "train." or "env." prefixes.
            msg = re.sub(rf"(?<![\w.-])(?:train\.|env\.)?{re.escape(field)}(?!\w)", names[field], msg)
        if msg == str(e):
            raise
        raise type(e)(msg) from None


Setting = Literal["standard", "difficult", "custom"]
Shape = Literal["all", "cylinder", "square", "rectangular", "cuboid"]
DEFAULT_SEED = 1_000_003  # distinct from training seeds (mjx_push.train.episodes.EvalSpec's default)
_CUSTOM = "(--setting custom only; default: Table I's)"


@dataclasses.dataclass
class EvalOptions:
    setting: Setting = "difficult"
    """standard: Table I; difficult: the paper's figure (mass 1-10 g, friction 0.2-0.3, height >= 0.052);
    custom: Table I with --mass, --friction, --min-height"""
    shape: Shape = "all"
    """all: even episodes cuboids, odd ones cylinders; square / rectangular: cuboids with equal /
    distinct sides; cuboid: either"""
    episodes: int = 100
    seed: int = DEFAULT_SEED
    """episode i's object, start and goal come from (seed, i) alone: the same for every policy,
    in eval and in deploy"""
    mass: Annotated[tuple[float, float] | None, tyro.conf.arg(metavar="LO HI", help_behavior_hint=_CUSTOM)] = None
    """object mass range (kg)"""
    friction: Annotated[tuple[float, float] | None, tyro.conf.arg(metavar="LO HI", help_behavior_hint=_CUSTOM)] = None
    """sliding friction range"""
    min_height: Annotated[float | None, tyro.conf.arg(metavar="M", help_behavior_hint=_CUSTOM)] = None
    """minimum full object height (m)"""
    video: Annotated[Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: none)")] = None
    """write the first --video-episodes episodes (top and under-table views) to a .gif,
    or an .mp4 (needs the mp4 extra: pip install 'mjx-push[mp4]')"""
    video_episodes: int = 2

    def check_options(self) -> None:
        """Raise ValueError naming the option at fault, before any work is done."""
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes < 1:
            raise ConfigError(f"--episodes must be a positive integer, got {self.episodes!r}")
        ranges = {"--mass": self.mass, "--friction": self.friction, "--min-height": self.min_height}
        given = [k for k, v in ranges.items() if v is not None]
        if given and self.setting != "custom":
            verb = "needs" if len(given) == 1 else "need"
            raise ConfigError(f"{' / '.join(given)} {verb} --setting custom (got --setting {self.setting})")
        with flag_errors(
            {
                "objects.mass": "--mass",
                "objects.friction": "--friction",
                "objects.min_height": "--min-height",
                "setting": "--setting",
                "shape": "--shape",
            }
        ):
            self.spec().object_config()  # validates the ranges
        if self.video is not None:
            if not isinstance(self.video_episodes, int) or self.video_episodes < 1:
                raise ConfigError(f"--video-episodes must be a positive integer, got {self.video_episodes!r}")
            from mjx_push import video
            from mjx_push.renderer import renderer_available, unavailable_reason

            try:
                video.check_writable(self.video)
            except ValueError as e:
                raise ConfigError(f"--video: {e}") from None
            if not renderer_available():
                raise ConfigError(f"--video: {unavailable_reason()}")

    def spec(self, batch: int = 20):
        """The evaluation protocol's `mjx_push.train.episodes.EvalSpec` for these options (recording the video's
        episodes)."""
        from mjx_push.train.episodes import EvalSpec  # imports JAX: not at CLI start-up

        record = min(self.video_episodes, self.episodes) if self.video is not None else 0
        return EvalSpec(
            setting=self.setting,
            shape=self.shape,
            episodes=self.episodes,
            seed=self.seed,
            batch=min(batch, self.episodes),
            mass=self.mass,
            friction=self.friction,
            min_height=self.min_height,
            record=record,
        )


def resolve_policy(path: Path, name: str = "POLICY"):
    """A run directory (its best policy), a saved policy (.msgpack/.json or their stem), an exported .npz
    or a shipped policy (`pretrained:NAME`) -> `mjx_push.train.runs.policies.Policy`. Errors name the option
    (`name`) and the path as the user typed it."""
    from mjx_push.export import pretrained
    from mjx_push.export.policy_file import load_as_policy
    from mjx_push.train.runs import policies

    path = pretrained.resolve(Path(path))
    if path.suffix == ".npz" and path.is_file():
        try:
            return load_as_policy(path)
        except ValueError as e:
            raise ConfigError(f"{name} {path}: {e}") from None
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


def set_error(e: ValueError) -> ConfigError:
    """A refused `--set` (train's and reproduce's): unknown paths name themselves; a bad value names its field."""
    return ConfigError(str(e) if str(e).startswith("--set") else f"--set: {e}")


# `--cpu render analytic` of eval and reproduce: the mask sources of a CPU MuJoCo run beside the MJX one.
CpuMasks = Annotated[
    tuple[Literal["render", "analytic"], ...],
    tyro.conf.arg(metavar="{render,analytic} ...", help_behavior_hint="(default: MJX only)"),
]


def check_cpu(sources: tuple[str, ...]) -> None:
    """Refuse `--cpu` sources given twice, or `render` where MuJoCo cannot render."""
    if len(set(sources)) != len(sources):
        raise ConfigError(f"--cpu lists a mask source twice: {' '.join(sources)}")
    if "render" in sources:
        from mjx_push.renderer import renderer_available, unavailable_reason

        if not renderer_available():
            raise ConfigError(f"--cpu render: {unavailable_reason()}; or --cpu analytic")


VIDEO_FPS = 5  # one frame per environment step


def open_video(path: Path):
    """An imageio writer for a .gif or an .mp4 (the mp4 extra), or a ConfigError saying what to install."""
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


def write_plan(path: Path, lines: list[str], log) -> None:
    """`--plan FILE` of reproduce and protocol: one command a line, for a scheduler; says what it wrote."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    log(f"{len(lines)} commands written to {path}:", *lines, sep="\n", markup=False)

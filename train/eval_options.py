"""Options shared by `mjx-push eval` (the MJX scene) and `mjx-push deploy` (CPU MuJoCo): the same names,
choices, defaults and checks, so both commands draw the same episodes (episode i's object, start and
goal come from the seed and i alone) and print the same table (`train.evaluate.metrics_table`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Literal

import tyro

from train.flags import flag_errors
from mjx_push.errors import ConfigError

Setting = Literal["standard", "difficult", "custom"]
Shape = Literal["all", "cylinder", "square", "rectangular", "cuboid"]
DEFAULT_SEED = 1_000_003  # distinct from training seeds (train.evaluate.EvalSpec's default)
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
        """The evaluation protocol's `train.evaluate.EvalSpec` for these options (recording the video's
        episodes)."""
        from train.evaluate import EvalSpec  # imports JAX: not at CLI start-up

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

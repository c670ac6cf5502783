"""`mjx-push stress POLICY`: a policy on the protocol's episodes under what a real cell brings
(`mjx_push.train.stress.stress`, docs/robustness.md)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Annotated

import tyro

from mjx_push.cli.options import flag_errors, resolve_policy
from mjx_push.errors import ConfigError
from mjx_push.train.config import Preset


@dataclasses.dataclass(kw_only=True)
class Stress:
    """Stress-test a policy: the evaluation protocol's episodes under each perturbation of the suite
    (masks, camera, latency, flange noise, velocity tracking, mass, friction, push rod) at mild,
    realistic and severe levels, beside the clean row; success within the radius per shape with 95 %
    intervals, the drop from clean (paired episodes), the final distances, and one robustness score
    (the mean success over the suite at the realistic level). docs/robustness.md says what each level
    stands for on a real Panda with a camera."""

    policy: Annotated[Path, tyro.conf.arg(metavar="POLICY"), tyro.conf.Positional]
    """a run directory, a saved policy, an exported .npz, a shipped policy (`pretrained:NAME`), or
    `expert`: the scripted expert (it reads ground truth, so only the physical rows reach it)"""
    perturbations: Annotated[
        tuple[str, ...] | None, tyro.conf.arg(metavar="NAME ...", help_behavior_hint="(default: the whole suite)")
    ] = None
    """rows of the suite to run (docs/robustness.md lists them; `all`: every row at once)"""
    levels: tuple[str, ...] = ("mild", "realistic", "severe")
    shapes: tuple[str, ...] = ("cylinder", "square", "rectangular")
    episodes: int = 50
    """episodes per cell (perturbation, level) and shape"""
    seed: Annotated[int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: the protocol's)")] = None
    """episode i's object, start and goal come from (seed, i) alone, as in `mjx-push eval`"""
    setting: str = "difficult"
    batch: int = 50
    """environments simulated at once (does not change the episodes)"""
    success_tau: Annotated[
        float | None, tyro.conf.arg(metavar="M", help_behavior_hint="(default: the radius the policy trained for)")
    ] = None
    preset: Annotated[Preset | None, tyro.conf.arg(metavar="PRESET", help_behavior_hint="(default: cpu)")] = None
    """POLICY expert only: the preset whose action box the expert acts in"""
    out: Annotated[
        Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: stress.json beside the policy)")
    ] = None
    """JSON with every cell's statistics and the score. Until the run ends, its finished chunks are
    kept in PATH.partial: the same command rerun after a kill or a session's end resumes from them"""
    fresh: bool = False
    """discard PATH.partial (a stopped run's finished chunks) and start over"""

    def config(self):
        """The suite's `StressConfig` from the options (errors name the option)."""
        from mjx_push.train import stress

        fields = dict(
            levels=tuple(self.levels),
            shapes=tuple(self.shapes),
            setting=self.setting,
            episodes=self.episodes,
            batch=self.batch,
            success_tau=self.success_tau,
        )
        if self.perturbations is not None:
            fields["perturbations"] = tuple(self.perturbations)
        if self.seed is not None:
            fields["seed"] = self.seed
        names = {f: "--" + f.replace("_", "-") for f in (*fields, "perturbations", "seed")}
        with flag_errors(names):
            return stress.StressConfig(**fields)

    def run(self) -> dict:
        from rich.console import Console

        from mjx_push.train import stress

        cfg = self.config()
        is_expert = str(self.policy) == "expert"
        if self.preset is not None and not is_expert:
            raise ConfigError("--preset chooses the scripted expert's action box: use it with POLICY expert")
        if is_expert:
            from mjx_push.train import presets
            from mjx_push.train.evaluate import ExpertPolicy

            policy = ExpertPolicy(presets.make("vpm", self.preset or "cpu"))
        else:
            policy = resolve_policy(self.policy)
        out = self.out or (
            Path("outputs/stress-expert.json")
            if is_expert
            else (self.policy if self.policy.is_dir() else Path(self.policy).parent) / "stress.json"
        )
        if str(self.policy).startswith("pretrained:") and self.out is None:
            out = Path(f"outputs/stress-{str(self.policy).split(':', 1)[1]}.json")
        out.parent.mkdir(parents=True, exist_ok=True)
        partial = stress.partial_path(out)
        if self.fresh and partial.exists():
            partial.unlink()
        console = Console()
        cells = len(cfg.cells())
        console.print(
            f"[bold]mjx-push stress[/] {self.policy}: {cells} cells x {len(cfg.shapes)} shapes x {cfg.episodes} "
            f"episodes (setting {cfg.setting}, seed {cfg.seed}; the first batch includes JIT compilation)",
            soft_wrap=True,
        )
        if partial.exists():
            console.print(f"  resuming from {partial} (--fresh starts over)", soft_wrap=True)
        result = stress.stress(
            policy, cfg, progress=lambda line: console.print(f"  {line}", soft_wrap=True), resume_from=partial
        )
        result["source"] = str(self.policy)
        console.print(stress.format_table(result), markup=False, soft_wrap=True)
        out.write_text(json.dumps(result, indent=2) + "\n")
        partial.unlink(missing_ok=True)  # the record holds every chunk now
        console.print(f"written {out} ({result['wall_s']:.0f} s)")
        return result

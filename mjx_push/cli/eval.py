"""`mjx-push eval`: a policy on the evaluation protocol's episodes in MJX (`mjx_push.train.evaluate.evaluate`), optionally beside CPU MuJoCo."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import tyro

from mjx_push.cli.options import CpuMasks, EvalOptions, check_cpu, resolve_policy
from mjx_push.train.config import Preset

from mjx_push.errors import ConfigError


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
    cpu: CpuMasks = ()
    """also run the same episodes in CPU MuJoCo (the deploy path: the NumPy policy) with these mask
    sources, and report, beside each simulator's table, how often their outcomes agree episode by
    episode and how their final distances correlate (docs/parity.md)"""

    def run(self) -> None:
        if self.cpu:
            if str(self.policy) == "expert":
                raise ConfigError("--cpu runs a trained policy's NumPy port: the scripted expert has none")
            check_cpu(self.cpu)
        record, out, res = self.evaluate()
        if self.cpu:
            record["cpu"] = self._cpu_runs(record)
        self.write(record, out)
        self.write_video(res)

    def evaluate(self) -> tuple[dict, Path, dict]:
        """Check the options, evaluate in MJX and print the table: (the JSON record, where it goes, the
        evaluation's full result)."""
        import numpy as np
        from rich.console import Console

        from mjx_push.train.evaluate import evaluate, metrics_table

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
            from mjx_push.train import presets
            from mjx_push.train.evaluate import ExpertPolicy

            policy = ExpertPolicy(presets.make("vpm", self.preset or "cpu"))
        else:
            policy = resolve_policy(self.policy)
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

    def _cpu_runs(self, record: dict) -> dict:
        """Each mask source's CPU MuJoCo run of the evaluation's episodes: its summary, its records and
        its agreement with the MJX run (`mjx_push.export.metrics.agreement_by_shape`)."""
        from rich.console import Console

        from mjx_push.export import pretrained, sim_eval
        from mjx_push.export.metrics import agreement_by_shape, summarize_records
        from mjx_push.export.numpy_policy import NumpyPolicy
        from mjx_push.train.evaluate import metrics_table

        console = Console()
        spec = self.spec(self.batch)
        path = pretrained.resolve(self.policy)
        if path.suffix == ".npz":
            policy = NumpyPolicy.from_file(path)
        else:  # a run directory or saved policy: its NumPy port
            policy = NumpyPolicy.from_policy(resolve_policy(self.policy), {"source": str(self.policy)})
        runs = {}
        for source in self.cpu:
            records = sim_eval.run_cpu(policy, spec, source, self.success_tau)
            summary = summarize_records(records)
            agree = agreement_by_shape(record["per_episode"], records)
            console.print(
                metrics_table(f"{policy.kind} / {spec.setting} / {spec.shape} (CPU MuJoCo, {source} masks)", summary)
            )
            console.print(
                f"MJX vs CPU MuJoCo ({source} masks): " + "; ".join(_agreement_line(g, a) for g, a in agree.items())
            )
            runs[source] = {"summary": summary, "agreement": agree, "episodes": records}
        return runs


def _agreement_line(group: str, a: dict) -> str:
    corr = "-" if a["final_distance_correlation"] is None else f"{a['final_distance_correlation']:.2f}"
    return (
        f"{group} {a['mjx_success']:.0%} / {a['cpu_success']:.0%} within the radius, same outcome in "
        f"{a['success_agreement']:.0%}, final distances r = {corr}"
    )

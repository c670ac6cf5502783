"""The presets of `mjx-push train --preset` (each a `mjx_push.train.config.RunConfig`: the learner, the
task, the scripted expert and the encoder), and the run configuration's files and `--set` overrides.

* ``smoke``: the whole pipeline (demonstrations, rollouts, updates, evaluation, checkpoints, best
  policy) on 2 CPU cores in a few minutes; it proves the plumbing, not the policy.
* ``cpu``: the README's main job: an agent that learns to push to 1 cm on 2 CPU cores in 8-12
  minutes on a fast machine, twice that on a slow one (VPM, 35,200 env steps, the steady-hold
  expert; within 1 cm on 100 standard episodes: docs/results.md).
* ``cpu-long``: 64,000 env steps with the teacher kept, for 1 cm (docs/results.md).
* ``teacher-free``: the comparison's recipe in one run, 128,000 env steps: ``cpu-long``'s 64,000 with
  the teacher, then the teacher annealed away by 80,000 (cloning weight and expert share to 0, the
  actor held to its copy of 64,000 by the anchor), then the agent's own to the end. Whether the anchor
  is let go too (``demo.anchor_release``) and whether the expert's episodes leave replay with the
  teacher (``demo.keep_after_anneal``) are chosen on selection episodes (docs/learners.md).
* ``reference``: the paper's reference code, one call of its training script: its action box and
  learner (no normalisation, symmetric critics, no demonstrations), 29,000 environment steps,
  10,000 random-action steps, one update per environment step, batch 256. That script resumed and
  added another 29,000 steps per call; this is not the paper's budget, and nothing learns at it.
* ``paper``: the budget the evidence asks for (millions of environment steps, as the model the paper
  builds on and HER pushing in general need), with the ``cpu`` preset's learner, sized for one GPU.

The ``cpu``, ``cpu-long`` and ``paper`` presets use the learner settings chosen by measurement
(`benchmarks/learning_ladder.py`; docs/results.md lists them and how each was chosen): a smaller action box
with a stiffer controller, input normalisation, a privileged LayerNorm critic, expert demonstrations
and behaviour cloning towards the expert's action at every stored step (DAgger-style labels; the
Q-filter is off: with it the young critic vetoed most labels and nothing learned). eGRU differs from uGRU only in the environment: the improved force
sampling.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
from pathlib import Path

from mjx_push import objects
from mjx_push.controller import ControllerConfig
from mjx_push.env import EnvConfig
from mjx_push.expert import ExpertConfig
from mjx_push.train import configio
from mjx_push.train.config import (
    AGENT_KINDS,
    PRESETS,
    AgentConfig,
    DemoConfig,
    LoopConfig,
    ReplayConfig,
    RunConfig,
    SACConfig,
    TrainConfig,
)
from mjx_push.errors import ConfigError


def env_for(agent: str, objects_cfg: objects.ObjectConfig | None = None, **env_fields) -> EnvConfig:
    """The task an agent trains on: eGRU draws masses with the improved sampling."""
    objects_cfg = objects_cfg or objects.ObjectConfig()
    mode = "improved" if agent == "egru" else "uniform"
    return EnvConfig(objects=dataclasses.replace(objects_cfg, mode=mode), **env_fields)


# The action box of the measured presets (EnvConfig's defaults are the paper's: +-1 m offsets, unit
# gain, 10-600 substeps). With a gain of 20 the flange settles on its target within ~150 substeps,
# so an action is a displacement of at most 5 cm (as in Fetch and panda-gym) and a_s mostly sets how
# long the step lasts; the scripted expert reaches 1 cm with it in a quarter of the paper's substeps
# per step (benchmarks/expert.py).
ACTION_BOX = dict(action_scale=0.05, substeps=(10, 200), controller=ControllerConfig(gain=20.0))

# The learner features every measured preset shares (AgentConfig / SACConfig / DemoConfig fields).
_AGENT = dict(obs_norm=True, critic_obs="privileged", critic_layer_norm=True, critic_hidden=(256, 256, 256))
_SAC_FEATURES = dict(init_alpha=0.05, target_clip=True, bc_weight=2.0, q_filter=False)
_DEMO = DemoConfig(warmup=True, fraction=0.25, label_all=True)

# The expert holds still with its usual step length instead of its shortest one, so its a_s label is
# the same at every step: cloners smoothed the jump into too-short steps near the goal, and the main
# job's 1 cm success rose most on cuboids (benchmarks/bc_gap.py, docs/history/).
_STEADY_EXPERT = ExpertConfig(hold_short=False)
# (Going round an overshot object always on one side, `circle_cut=2.2`, measured no better over three
# seeds of the main job; docs/history/.)

# "cpu", the README's main job. Evaluations cost about four batches each (100 episodes in chunks of
# 32), so it evaluates once, at the end; metrics.csv and the progress lines follow training success per batch.
# 35,200 env steps take about 8-12 minutes alone on 2 fast cores with an empty compilation cache (a
# batch after the first about 20 s; docs/performance.md), 48,000 about 12; slower 2-core machines
# take twice that.
_CPU = dict(
    loop=dict(
        num_envs=32,
        total_env_steps=35_200,
        warmup_env_steps=4_800,
        utd=0.25,
        eval_every_env_steps=35_200,
        eval_episodes=100,
    ),
    sac=dict(batch_size=256, **_SAC_FEATURES),
    replay=300_000,
    agent=_AGENT,
    demo=_DEMO,
    env=ACTION_BOX,
    expert=_STEADY_EXPERT,
)

_PRESETS = {
    # One batch of expert demonstrations, 100 updates, one evaluation: two rollouts in all, since on
    # 2 CPU cores compilation is the whole cost.
    "smoke": dict(
        loop=dict(
            num_envs=8, total_env_steps=800, warmup_env_steps=400, utd=0.25, eval_every_env_steps=800, eval_episodes=8
        ),
        sac=dict(batch_size=64, bc_batch_size=32, **_SAC_FEATURES),
        replay=50_000,
        agent=_AGENT,
        demo=_DEMO,
        env=ACTION_BOX,
        expert=_STEADY_EXPERT,
    ),
    "cpu": _CPU,
    # The main job's learner and teacher for 64,000 env steps, evaluated every 16,000 (the earlier
    # comparisons' budget, docs/history/). Runs of the shortest hold (the first comparison's) are
    # `--set expert.hold_short=true`.
    "cpu-long": {**_CPU, "loop": {**_CPU["loop"], "total_env_steps": 64_000, "eval_every_env_steps": 16_000}},
    # cpu-long's cloning, then the teacher annealed away and the agent alone for as long again. Its
    # comparison scores the final actor, so in-run evaluations (about four batches' time each) only
    # draw the curve: one every 32,000 env steps, at the teacher's last step among them.
    "teacher-free": {
        **_CPU,
        "loop": {**_CPU["loop"], "total_env_steps": 128_000, "eval_every_env_steps": 32_000},
        "sac": {**_CPU["sac"], "anchor_weight": _SAC_FEATURES["bc_weight"]},
        "demo": dataclasses.replace(_DEMO, anneal_start=64_000, anneal_end=80_000),
    },
    "reference": dict(
        loop=dict(
            num_envs=10,
            total_env_steps=29_000,
            warmup_env_steps=10_000,
            utd=1.0,
            eval_every_env_steps=5_000,
            eval_episodes=100,
        ),
        sac=dict(batch_size=256),
        replay=300_000,
        agent={},
        demo=DemoConfig(),
        env={},
    ),
    "paper": dict(
        loop=dict(
            num_envs=2048,
            total_env_steps=3_072_000,
            warmup_env_steps=102_400,
            utd=0.125,
            eval_every_env_steps=204_800,
            eval_episodes=2048,
        ),
        sac=dict(batch_size=1024, bc_batch_size=256, **_SAC_FEATURES),
        replay=3_000_000,
        agent=_AGENT,
        demo=_DEMO,
        env=ACTION_BOX,
        expert=_STEADY_EXPERT,
    ),
}


def make(agent: str, preset: str = "cpu", seed: int = 0) -> RunConfig:
    if preset not in PRESETS:
        raise ConfigError(f"preset must be one of {PRESETS}, got {preset!r}")
    if agent not in AGENT_KINDS:
        raise ConfigError(f"agent must be one of {AGENT_KINDS}, got {agent!r}")
    p = _PRESETS[preset]
    env = env_for(agent, **p["env"])
    train = TrainConfig(
        agent=AgentConfig(agent, **p["agent"]),
        sac=SACConfig(**p["sac"]),
        replay=ReplayConfig(capacity_transitions=p["replay"]),
        loop=LoopConfig(seed=seed, **p["loop"]),
        demo=p["demo"],
    )
    return RunConfig(agent=agent, preset=preset, train=train, env=env, expert=p.get("expert", ExpertConfig()))


def override(cfg: RunConfig, **fields) -> RunConfig:
    """Learner fields by dotted name under ``train``, e.g. override(cfg, **{"loop.num_envs": 16,
    "sac.lr": 3e-4}); None values are ignored. The typed command-line flags go through here, and this
    through ``with_overrides`` (one override path). The preset name stays that of the base; the run's
    config.json holds every value."""
    return with_overrides(cfg, {f"train.{dotted}": value for dotted, value in fields.items() if value is not None})


def parse_overrides(items) -> dict:
    """["train.sac.bc_weight=0", "env.substeps=[10,600]"] -> {dotted path: value}; values are JSON
    (numbers, true/false, lists, quoted strings) or else taken as plain strings."""
    out = {}
    for item in items:
        path, sep, text = item.partition("=")
        if not sep or not path:
            raise ConfigError(f"--set takes PATH=VALUE (e.g. train.sac.bc_weight=0), got {item!r}")
        try:
            out[path] = json.loads(text)
        except json.JSONDecodeError:
            out[path] = text
    return out


# Fields the learner's configuration once held, copies of facts of the task the environment defines
# (the learner now reads them from its adapter), with the field that holds each. Records written before
# (config.json, checkpoints, saved and exported policies) still carry them: `config_from_dict` drops a
# copy equal to the environment's value and refuses one that differs; `--set` on one names its source.
REMOVED_TASK_COPIES = {"train.loop.episode_len": "env.episode_length", "train.replay.success_tau": "env.success_tau"}


def _same(a, b) -> bool:
    try:
        return abs(float(a) - float(b)) <= 1e-12
    except (TypeError, ValueError):
        return a == b


def set_flag(overrides: dict | None) -> str:
    """` --set PATH=VALUE ...` giving `overrides` back (values in JSON, quoted for a shell), or ''."""
    if not overrides:
        return ""
    return " --set " + " ".join(
        shlex.quote(f"{k}={json.dumps(v, separators=(',', ':'))}") for k, v in overrides.items()
    )


def with_overrides(cfg: RunConfig, overrides: dict) -> RunConfig:
    """``cfg`` with the fields at dotted paths (``train.sac.bc_weight``, ``env.controller.gain``, ...)
    replaced and validated once all are set. The task's facts are the environment's fields alone: a
    removed learner's copy (REMOVED_TASK_COPIES) set to another value than its source is refused,
    naming the field to set instead (the same value is ignored). Raises ConfigError naming an unknown
    path or a bad value."""
    d = configio.to_dict(cfg)
    for copy, source in REMOVED_TASK_COPIES.items():
        if copy in overrides and not _same(overrides[copy], overrides.get(source, _at(d, source))):
            raise ConfigError(
                f"--set {copy}: the learner reads the task's value from the environment; set {source} instead"
            )
    for dotted, value in overrides.items():
        if dotted in REMOVED_TASK_COPIES:
            continue
        *parents, leaf = dotted.split(".")
        node = d
        for part in parents:
            if not isinstance(node.get(part), dict):
                raise ConfigError(f"--set {dotted}: unknown setting (no section {part!r})")
            node = node[part]
        if leaf not in node:
            raise ConfigError(f"--set {dotted}: unknown setting (no field {leaf!r})")
        node[leaf] = value
    return configio.from_dict(RunConfig, d, "config")


def _at(d: dict, dotted: str):
    for part in dotted.split("."):
        d = d[part]
    return d


# --- a RunConfig on disk (config.json, checkpoint and policy records) ------------------------------
def config_dict(cfg: RunConfig) -> dict:
    return configio.to_dict(cfg)


def config_from_dict(d: dict) -> RunConfig:
    return configio.from_dict(RunConfig, without_task_copies(d), "config")


def without_task_copies(d: dict) -> dict:
    """Config dict ``d`` without the learner's former copies of the task's facts (REMOVED_TASK_COPIES),
    as records written before their removal hold them: a copy equal to the environment's value is
    dropped, one that differs is refused by name (such a record does not describe one task). ``d`` is
    left as it is."""
    if not isinstance(d, dict):
        return d
    out = None
    for copy, source in REMOVED_TASK_COPIES.items():
        (section, part, leaf), (env_key, env_field) = copy.split("."), source.split(".")
        node = d.get(section, {}).get(part) if isinstance(d.get(section), dict) else None
        if not isinstance(node, dict) or leaf not in node:
            continue
        env = d.get(env_key) if isinstance(d.get(env_key), dict) else {}
        if env_field in env:
            value = env[env_field]
        else:  # a record that leaves the field to its default
            value = getattr(EnvConfig(), env_field)
        if not _same(node[leaf], value):
            raise ConfigError(
                f"config.{copy} ({node[leaf]!r}) differs from config.{source} ({value!r}): the record "
                f"describes two tasks; the learner reads {source} alone (make {copy} equal it, or remove it)"
            )
        if out is None:
            out = json.loads(json.dumps(d))  # a deep copy of plain data
        del out[section][part][leaf]
    return d if out is None else out


def load_config(path: Path) -> RunConfig:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"run config not found: {path}")
    try:
        return config_from_dict(json.loads(path.read_text()))
    except json.JSONDecodeError as e:
        raise ConfigError(f"run config {path} is not valid JSON: {e}") from None

"""A run forked from another run's checkpoint: the learner's whole state (networks, optimisers, replay
buffer, input statistics, env-step count) trained on under new settings in a new run directory.

What it is for: changing a schedule part-way through without retraining what came before, e.g.
annealing the teacher away from a converged cloning agent (``train.demo.anneal_*``,
``train.sac.anchor_weight``), a tighter success radius, other objects, a longer budget with another
learning rate. ``--resume`` cannot: it continues a run exactly and so refuses a changed configuration.

The fork counts env steps on from the checkpoint's (schedules in env steps stay absolute), keeps its
own best actor (only its own evaluations count), anchors the actor (``train.sac.anchor_weight``) no
earlier than the fork, and draws its own random numbers (the checkpoint's key folded with the fork's
``train.loop.seed``). The source run is only read, never changed, and may still be training. The new
run directory holds a checkpoint at the fork from the start, so an interrupted fork resumes as any run
does, and ``forked_from.json`` names its source.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp

from mjx_push.errors import ConfigError
from mjx_push.train import configio
from mjx_push.train.runs import atomic
from mjx_push.train.runs.checkpoints import Checkpoints, saved_steps
from mjx_push.train.loop import TrainState
from mjx_push.train.config import RunConfig
from mjx_push.train.presets import config_dict, load_config

# What the stored state is made of: the networks' shapes and inputs, the encoder that made the replay's
# latents, the replay's layout. A fork that changed these would train on state that means something
# else (or does not fit), so they are refused by name before anything is read.
FIXED = (
    "agent",
    "train.agent.",
    "encoder",
    "train.replay.capacity_transitions",
    "train.loop.num_envs",
    "train.loop.data_parallel",
    "env.episode_length",
)
RECORD = "forked_from.json"


@dataclasses.dataclass(frozen=True)
class ForkSource:
    run_dir: Path
    env_steps: int | None = None  # the checkpoint to fork (None: the run's latest)


def source_config(source: ForkSource) -> RunConfig:
    """The configuration of the run to fork (its config.json), with a clear error when there is none."""
    run_dir = Path(source.run_dir)
    if not (run_dir / "config.json").is_file():
        raise ConfigError(f"--fork-from: {run_dir} is not a run directory (no config.json)")
    return load_config(run_dir / "config.json")


def fork_step(source: ForkSource) -> int:
    """The env steps of the checkpoint to fork, checked to exist (read from the directory names, so
    nothing is opened)."""
    ckpt_dir = Path(source.run_dir) / "checkpoints"
    steps = saved_steps(ckpt_dir)
    if not steps:
        raise ConfigError(f"--fork-from: no checkpoint in {ckpt_dir}")
    step = steps[-1] if source.env_steps is None else source.env_steps
    if step not in steps:
        raise ConfigError(
            f"--fork-from: {source.run_dir} has no checkpoint at {step:,} env steps (it has: "
            + ", ".join(f"{s:,}" for s in steps)
            + ")"
        )
    return step


def check_fork(source: ForkSource, cfg: RunConfig) -> tuple[int, list[str]]:
    """Everything a fork can check before anything is built or written: its source, checkpoint and
    settings. Returns the checkpoint's env steps and the settings the fork changes."""
    source_cfg = source_config(source)  # first: "not a run directory" says more than "no checkpoint"
    step = fork_step(source)
    return step, fork_changes(source_cfg, cfg, step)


def fork_changes(source_cfg: RunConfig, cfg: RunConfig, env_steps: int) -> list[str]:
    """The settings the fork changes (dotted paths with old and new values). Raises ConfigError when it
    changes a fixed one (`FIXED`) or does not train past the checkpoint it starts from."""
    changes = configio.differences(config_dict(source_cfg), config_dict(cfg))
    fixed = [c for c in changes if any(c.startswith(f if f.endswith(".") else f + ":") for f in FIXED)]
    if fixed:
        raise ConfigError(
            "--fork-from: a fork keeps its source's networks, encoder and replay layout; these settings "
            "differ: " + "; ".join(fixed[:6])
        )
    total = cfg.train.loop.total_env_steps
    if total <= env_steps:
        raise ConfigError(
            f"--fork-from: train.loop.total_env_steps ({total:,}) must exceed the forked checkpoint's "
            f"{env_steps:,} env steps (a fork counts on from there)"
        )
    return changes


def fork_state(template: TrainState, cfg: RunConfig, source: ForkSource) -> tuple[TrainState, dict]:
    """The state `cfg`'s run starts from: `source`'s checkpoint read into `template` (an initial state of
    `cfg`), with its own best actor, anchor and random key. Returns (state, record for RECORD)."""
    run_dir = Path(source.run_dir).absolute()
    source_cfg, step = source_config(source), fork_step(source)
    changes = fork_changes(source_cfg, cfg, step)
    state, _ = Checkpoints(run_dir / "checkpoints", read_only=True).restore(template, source_cfg, step)
    actor = state.sac.actor_params
    state = state.replace(
        key=jax.random.fold_in(state.key, cfg.train.loop.seed),
        best_actor_params=jax.tree.map(jnp.copy, actor),
        best_eval_reward=jnp.array(-jnp.inf, jnp.float32),
        best_eval_success=jnp.zeros((), jnp.float32),
        best_env_steps=jnp.array(-1, jnp.int32),
        anchor_actor_params=jax.tree.map(jnp.copy, actor),
    )
    record = {"run_dir": str(run_dir), "env_steps": int(step), "changes": changes}
    return state, record


def write_record(run_dir: Path, record: dict) -> None:
    atomic.write_text(Path(run_dir) / RECORD, json.dumps(record, indent=2) + "\n")


def read_record(run_dir: Path) -> dict | None:
    path = Path(run_dir) / RECORD
    return json.loads(path.read_text()) if path.is_file() else None

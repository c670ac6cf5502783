"""A training run on disk: the run directory, its lock and checks, and the run itself (train, checkpoint,
resume exactly, save policies and a summary). Its parts live apart: checkpoints in mjx_push.train.runs.checkpoints,
saved policies in mjx_push.train.runs.policies, the metric log in mjx_push.train.runs.metric_log, config files in mjx_push.train.presets.

Run directory layout (``mjx-push train --run-dir DIR``):

    config.json          the full RunConfig (every value, not just the preset name)
    metrics.csv          one row per episode batch (env steps, throughput, losses, evaluations)
    tb/                  TensorBoard scalars, x axis = environment steps
    checkpoints/<step>/  orbax: the whole TrainState (params, optimiser states, replay buffer, RNG key,
                         counters, best params) + a JSON record with the config; step = env steps
    best_policy.msgpack  actor params with the best evaluation mean reward, and the encoder
    best_policy.json     what they are: agent, configs, evaluation scores, encoder record
    final_policy.*       the same for the last actor params
    summary.json         wall time, compile time, throughput, best scores

Environments are reset at every episode batch, so a checkpoint between batches holds everything a
run needs to continue: resuming replays the remaining batches exactly (bitwise on CPU).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import jax
import numpy as np

from mjx_push import encoder as enc
from mjx_push.train import configio, data_parallel
from mjx_push.train.runs import atomic
from mjx_push.train.runs.signals import StopOnSignal
from mjx_push.train.runs.lock import RunLock
from mjx_push.train.adapter import EnvAdapter
from mjx_push.train.loop import Runner, TrainState, make_train
from mjx_push.train.loop import train as train_loop
from mjx_push.train.runs.checkpoints import Checkpoints, saved_steps
from mjx_push.train.runs.fork import ForkSource, check_fork, fork_state, read_record, write_record
from mjx_push.train.runs.metric_log import MetricLog
from mjx_push.train.runs.policies import save_policy
from mjx_push.train.config import RunConfig
from mjx_push.train.presets import config_dict, load_config
from mjx_push.errors import ConfigError


def _barrier(name: str) -> None:
    """Wait for every process of a multi-process run (nothing to wait for in one process)."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


def _check_same_config(run_dir: Path, cfg: RunConfig) -> int | None:
    """Refuse a resume of `run_dir` with another configuration than its own, except the same run trained
    longer (a larger ``train.loop.total_env_steps``): then its saved total env steps, else None."""
    saved = load_config(run_dir / "config.json")
    if configio.trained_longer(config_dict(saved), config_dict(cfg)):
        if cfg.train.sac.lr_decay:
            raise ConfigError(
                f"--resume: {run_dir} decays its learning rate over its "
                f"{saved.train.loop.total_env_steps:,} env steps (train.sac.lr_decay): training it longer "
                "would change the steps it has already taken; train a new run"
            )
        return saved.train.loop.total_env_steps
    diff = configio.differences(config_dict(saved), config_dict(cfg))
    if diff:
        raise ConfigError(f"--resume: {run_dir} was started with a different configuration: " + "; ".join(diff[:6]))
    return None


def prepare_dir(run_dir: Path, cfg: RunConfig, resume: bool, write: bool = True) -> int | None:
    """Check `run_dir` for a new run or a resume of `cfg`, and (`write`) create it and its config.
    A resume whose `cfg` only asks for more env steps trains the run longer (`_start_longer`, once its
    checkpoint has been read): returns the run's earlier total then, else None."""
    run_dir = Path(run_dir)
    has_ckpt = bool(saved_steps(run_dir / "checkpoints"))
    if resume:
        if not has_ckpt:
            raise ConfigError(f"--resume: no checkpoint in {run_dir / 'checkpoints'}")
        return _check_same_config(run_dir, cfg)
    else:
        if has_ckpt or (run_dir / "metrics.csv").exists():
            raise ConfigError(
                f"run directory {run_dir} already holds a run; pass --resume to continue it or choose another --run-dir"
            )
        if write:
            run_dir.mkdir(parents=True, exist_ok=True)
            atomic.write_text(run_dir / "config.json", json.dumps(config_dict(cfg), indent=2) + "\n")
    return None


def _start_longer(run_dir: Path, cfg: RunConfig) -> None:
    """The run in `run_dir` now trains for `cfg`'s longer total: config.json takes it and summary.json
    goes (the run is unfinished again; checkpoints, logs and saved policies stay, and the end of the
    longer run rewrites them). Called after the checkpoint restored, so a refused resume changes nothing."""
    atomic.write_text(run_dir / "config.json", json.dumps(config_dict(cfg), indent=2) + "\n")
    (run_dir / "summary.json").unlink(missing_ok=True)


class RunFinished(ValueError):
    """`--resume` of a run that has already finished: nothing to do (the message says so)."""


def finished_summary(run_dir: Path, cfg: RunConfig) -> dict | None:
    """The summary of `run_dir` if its run has finished (summary written, last checkpoint at the end)."""
    run_dir = Path(run_dir)
    path = run_dir / "summary.json"
    if not path.is_file():
        return None
    loop, T = cfg.train.loop, cfg.env.episode_length
    if max(saved_steps(run_dir / "checkpoints"), default=-1) < loop.num_iterations(T) * loop.env_steps_per_iteration(T):
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        return None


def check_not_finished(run_dir: Path, cfg: RunConfig) -> None:
    """Raise RunFinished if `run_dir`'s run of `cfg` has finished (before anything is opened or written)."""
    done = finished_summary(run_dir, cfg)
    if done is not None:
        _check_same_config(run_dir, cfg)  # a different configuration is the more useful message
        raise RunFinished(
            f"{run_dir} has finished ({done.get('env_steps', '?')} env steps, summary.json): "
            "--resume has nothing to continue; --resume --total-env-steps N (more than it has) trains it longer."
        )


def resume_config(run_dir: Path, total_env_steps: int | None = None) -> RunConfig:
    """The configuration a resume of `run_dir` continues: its own (config.json), trained for
    `total_env_steps` in all when given (longer only: a resume cannot shorten a run)."""
    run_dir = Path(run_dir)
    if not (run_dir / "config.json").is_file():
        raise ConfigError(
            f"--resume: no run directory {run_dir}"
            if not run_dir.is_dir()
            else f"--resume: {run_dir} holds no run (no config.json)"
        )
    cfg = load_config(run_dir / "config.json")
    total = cfg.train.loop.total_env_steps
    if total_env_steps is None or total_env_steps == total:
        return cfg
    if total_env_steps < total:
        raise ConfigError(
            f"--total-env-steps {total_env_steps:,} with --resume: the run in {run_dir} trains for {total:,} "
            "env steps; --resume can train it longer, not shorter"
        )
    from mjx_push.train.presets import with_overrides

    return with_overrides(cfg, {"train.loop.total_env_steps": total_env_steps})


@dataclass(frozen=True)
class Start:
    """What `run` found before it started: the fork's checkpoint and the settings it changes (None and ()
    for a new run or a resume)."""

    fork_step: int | None = None
    fork_changes: tuple[str, ...] = ()


def run(
    cfg: RunConfig,
    run_dir: Path,
    *,
    resume: bool = False,
    adapter: EnvAdapter | None = None,
    checkpoint_every: int = 10,
    stop_after: int | None = None,
    on_iteration: Callable[[dict], None] | None = None,
    substep_chunk: int | None = None,
    stop_on_signal: bool = False,
    fork: ForkSource | None = None,
    on_start: Callable[[Start], None] | None = None,
) -> tuple[dict, TrainState]:
    """Train `cfg` in `run_dir` (with `resume`, from its latest checkpoint; a `cfg` that differs from
    the run's own only by a larger ``train.loop.total_env_steps`` trains it longer, finished or not,
    exactly as a run of that length from the start would have trained, except for the evaluation it
    had at its earlier end; see `prepare_dir`). Checkpoints after every `checkpoint_every` batches, at every
    evaluation and at the end. `stop_after`: stop (as if killed) after that many batches of this call.
    `adapter` replaces the MJX task (tests use the toy task). `substep_chunk`: substeps per tick of the
    MJX task's scheduler (0: lockstep; None: the default); it changes speed, not episodes, so it is not
    part of the run's configuration. `stop_on_signal`: SIGINT / SIGTERM stop the run after the current
    batch with a checkpoint (`mjx_push.train.runs.signals`); the summary then holds "interrupted_at_env_steps" and
    "signal". `fork`: a new run that starts from another run's checkpoint (`mjx_push.train.runs.fork`) with `cfg`'s
    settings. One process at a time may run in a directory (`mjx_push.train.runs.lock`); resuming a finished run
    raises `RunFinished` and changes nothing. These rules are checked here, once: `on_start` is called
    when they hold, before anything is built (a command prints its header there). In a multi-process run (`mjx_push.train.data_parallel`) every
    process calls this with the same arguments and directory (a shared file system); process 0 takes
    the lock and writes the logs, policies and summary, all write their shards of each checkpoint.
    Returns (summary, final state)."""
    run_dir = Path(run_dir)
    start = Start()
    if fork is not None:
        if resume:
            raise ConfigError(
                "--resume continues the run in --run-dir; --fork-from starts a new one: pass one of them "
                "(an interrupted fork continues with --resume alone)"
            )
        step, changes = check_fork(fork, cfg)
        start = Start(step, tuple(changes))
    if resume:
        check_not_finished(run_dir, cfg)
        if not run_dir.is_dir():
            raise ConfigError(f"--resume: no checkpoint in {run_dir / 'checkpoints'} ({run_dir} does not exist)")
    if on_start is not None:
        on_start(start)
    if not resume and data_parallel.is_primary():
        run_dir.mkdir(parents=True, exist_ok=True)
    lock = RunLock(run_dir) if data_parallel.is_primary() else contextlib.nullcontext()
    with lock, StopOnSignal() if stop_on_signal else contextlib.nullcontext() as stop:
        return _run_locked(
            cfg,
            run_dir,
            resume=resume,
            adapter=adapter,
            checkpoint_every=checkpoint_every,
            stop_after=stop_after,
            on_iteration=on_iteration,
            substep_chunk=substep_chunk,
            stop=stop,
            fork=fork,
        )


@dataclass
class _Clock:
    """Wall time of the batches one call of `run` trains."""

    start: float = dataclasses.field(default_factory=time.perf_counter)
    last: float = dataclasses.field(init=False)
    first_batch_s: float | None = None
    batches: int = 0

    def __post_init__(self):
        self.last = self.start

    def tick(self) -> tuple[float, float]:
        """-> (seconds since the previous batch, seconds since the start)."""
        now = time.perf_counter()
        dt, self.last = now - self.last, now
        self.first_batch_s = dt if self.first_batch_s is None else self.first_batch_s
        self.batches += 1
        return dt, now - self.start


def _run_locked(
    cfg: RunConfig,
    run_dir: Path,
    *,
    resume: bool,
    adapter: EnvAdapter | None,
    checkpoint_every: int,
    stop_after: int | None,
    on_iteration: Callable[[dict], None] | None,
    substep_chunk: int | None,
    stop: StopOnSignal | None,
    fork: ForkSource | None = None,
) -> tuple[dict, TrainState]:
    primary = data_parallel.is_primary()
    # Every process checks (what process 0 writes here, the config, none of the checks reads); the
    # others wait for the directory before they open its checkpoints.
    earlier_total = prepare_dir(run_dir, cfg, resume, write=primary)
    _barrier("prepared the run directory")
    encoder_params = enc.load(cfg.encoder and Path(cfg.encoder))
    loop = cfg.train.loop
    if adapter is None:
        from mjx_push.train.push_task import DEFAULT_SUBSTEP_CHUNK, run_adapter

        adapter = run_adapter(cfg, encoder_params, DEFAULT_SUBSTEP_CHUNK if substep_chunk is None else substep_chunk)
    # The learner reads the task's facts from the adapter; the run's record (config.json) from env.
    T = cfg.env.episode_length
    if (adapter.episode_len, adapter.success_tau) != (T, cfg.env.success_tau):
        raise ConfigError(
            f"the environment given has episodes of {adapter.episode_len} steps and success radius "
            f"{adapter.success_tau}; the run's env.episode_length and env.success_tau are "
            f"{T} and {cfg.env.success_tau}"
        )
    trainer = make_train(cfg.train, adapter)
    runner = Runner(trainer)
    ckpts = Checkpoints(run_dir / "checkpoints")
    state = runner.init(jax.random.PRNGKey(loop.seed))
    resumed_from = None
    if resume:
        state, meta = ckpts.restore(state, cfg)
        resumed_from = int(state.env_steps)
        if earlier_total is not None and primary:
            _start_longer(run_dir, cfg)
    if fork is not None:  # the new run's first checkpoint is the source's state: from here on it is a resume
        state, forked = fork_state(state, cfg, fork)
        resumed_from = int(state.env_steps)
        ckpts.save(state, cfg, {"history_rows": 0, "forked_from": forked})
        if primary:
            write_record(run_dir, forked)
    log = MetricLog(run_dir, resumed_from, write=primary)

    clock = _Clock()

    def on_batch(ts: TrainState, metrics: dict) -> bool:
        """After each batch (and its evaluation): timing, logs, checkpoints; True stops the run."""
        dt, metrics["wall_s"] = clock.tick()
        metrics["iteration_s"] = dt
        metrics["env_steps_per_s"] = loop.env_steps_per_iteration(T) / dt
        metrics["updates_per_s"] = (loop.updates_per_iteration(T) / dt) if metrics["learning"] else 0.0
        log.write(metrics)
        if on_iteration is not None and primary:
            on_iteration(metrics)
        i = int(ts.env_steps) // loop.env_steps_per_iteration(T) - 1
        last = i == loop.num_iterations(T) - 1
        interrupted = stop is not None and stop.requested is not None
        if last or interrupted or "eval/mean_reward" in metrics or (i + 1) % checkpoint_every == 0:
            ckpts.save(ts, cfg, {"history_rows": len(log.rows)})
        return (interrupted or (stop_after is not None and clock.batches >= stop_after)) and not last

    try:
        state, _ = train_loop(None, cfg.train, adapter, callback=on_batch, state=state, runner=runner)
    finally:
        log.close()
    if int(state.env_steps) < loop.num_iterations(T) * loop.env_steps_per_iteration(T):
        stopped = {"stopped_at_env_steps": int(state.env_steps)}
        if stop is not None and stop.requested is not None:
            stopped.update(interrupted_at_env_steps=int(state.env_steps), signal=stop.requested)
        return stopped, state

    scores = {
        "best_eval_mean_reward": float(state.best_eval_reward),
        "best_eval_success_rate": float(state.best_eval_success),
        "best_env_steps": int(state.best_env_steps),
    }
    if not primary:
        return {**scores, "env_steps": int(state.env_steps), "run_dir": str(run_dir)}, state
    save_policy(run_dir / "best_policy", cfg, state.best_actor_params, encoder_params, scores)
    last_eval = next((r for r in reversed(log.rows) if r.get("eval/mean_reward") not in (None, "")), {})
    save_policy(
        run_dir / "final_policy",
        cfg,
        state.sac.actor_params,
        encoder_params,
        {
            "eval_mean_reward": float(last_eval.get("eval/mean_reward", np.nan)),
            "eval_success_rate": float(last_eval.get("eval/success_rate", np.nan)),
            "env_steps": int(state.env_steps),
        },
    )
    rows = log.rows
    steady = [float(r["iteration_s"]) for r in rows[1:] if r.get("eval/mean_reward") in (None, "")]
    summary = {
        **scores,
        "env_steps": int(state.env_steps),
        "updates": int(state.sac.step),
        "wall_s": time.perf_counter() - clock.start,
        "first_batch_s": clock.first_batch_s,
        "steady_env_steps_per_s": (loop.env_steps_per_iteration(T) / np.mean(steady)) if steady else None,
        "resumed_from_env_steps": resumed_from,
        **({"forked_from": forked} if (forked := read_record(run_dir)) is not None else {}),
        **({"trained_longer_from_env_steps": earlier_total} if earlier_total is not None else {}),
        "run_dir": str(run_dir),
    }
    atomic.write_text(run_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary, state

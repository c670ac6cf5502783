"""A training run on disk: run directory, logs, orbax checkpoints, exact resume, saved policies.

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
import csv
import io
import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
from flax import serialization

from mjx_push import encoder as enc
from train import atomic, configio, data_parallel
from train.interrupt import StopOnSignal
from train.run_lock import RunLock
from train.adapter import EnvAdapter
from train.loop import Runner, TrainState, make_train
from train.loop import train as train_loop
from train.presets import RunConfig
from mjx_push.errors import ConfigError

POLICY_FORMAT = "mjx-push-policy"
POLICY_VERSION = 1
CHECKPOINT_FORMAT = "mjx-push-checkpoint"
CHECKPOINT_VERSION = 1


def config_dict(cfg: RunConfig) -> dict:
    return configio.to_dict(cfg)


def config_from_dict(d: dict) -> RunConfig:
    return configio.from_dict(RunConfig, d, "config")


def load_config(path: Path) -> RunConfig:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"run config not found: {path}")
    try:
        return config_from_dict(json.loads(path.read_text()))
    except json.JSONDecodeError as e:
        raise ConfigError(f"run config {path} is not valid JSON: {e}") from None


# --- checkpoints -------------------------------------------------------------------------------------
class Checkpoints:
    """Orbax checkpoints of a TrainState, keyed by environment steps, the last `keep` kept."""

    def __init__(self, directory: Path, keep: int = 2):
        self.directory = Path(directory).absolute()
        # A checkpoint is written into a temporary directory and renamed when complete, so a kill mid-write
        # leaves the previous checkpoint as the latest; such leftovers are removed here, before the manager
        # starts. (Orbax's own cleanup runs in a background thread: two managers of one directory in a
        # process, e.g. a check of the latest step and then a resume, raced to delete the same folder.)
        for leftover in self.directory.glob("*.orbax-checkpoint-tmp*"):
            shutil.rmtree(leftover, ignore_errors=True)
        options = ocp.CheckpointManagerOptions(
            max_to_keep=keep, enable_async_checkpointing=False, create=True, cleanup_tmp_directories=False
        )
        self.manager = ocp.CheckpointManager(self.directory, options=options)

    def save(self, state: TrainState, config: RunConfig, extra: dict) -> int:
        step = int(state.env_steps)
        meta = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "config": config_dict(config), **extra}
        self.manager.save(
            step, args=ocp.args.Composite(state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)), force=True
        )
        self.manager.wait_until_finished()
        return step

    def latest(self) -> int | None:
        return self.manager.latest_step()

    def restore(self, template: TrainState, config: RunConfig, step: int | None = None) -> tuple[TrainState, dict]:
        """The checkpoint at `step` (default latest). Raises ValueError with the reason when there is
        none, when it was made by another configuration, or when its arrays are unreadable."""
        step = self.latest() if step is None else step
        if step is None:
            raise ConfigError(f"no checkpoint in {self.directory}")
        try:
            meta = self.manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]
        except Exception as e:
            raise ConfigError(
                f"checkpoint {self.directory}/{step} is corrupt (its record cannot be read): {e}"
            ) from None
        if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
            raise ConfigError(f"{self.directory}/{step} is not an mjx-push checkpoint")
        if meta.get("version") != CHECKPOINT_VERSION:
            raise ConfigError(
                f"checkpoint {self.directory}/{step} has format version {meta.get('version')}, "
                f"this mjx-push reads version {CHECKPOINT_VERSION}"
            )
        try:  # read through the schema, so a field added since (with its default) is no difference
            saved = config_dict(config_from_dict(meta.get("config", {})))
        except ConfigError:
            saved = meta.get("config", {})
        diff = configio.differences(saved, config_dict(config))
        if diff:
            raise ConfigError(
                f"checkpoint {self.directory}/{step} was made with a different configuration: " + "; ".join(diff[:6])
            )
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, template)
        try:
            state = self.manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))[
                "state"
            ]
        except Exception as e:
            raise ConfigError(
                f"checkpoint {self.directory}/{step} is corrupt or does not match this run's "
                f"state (shapes, dtypes or structure): {type(e).__name__}: {str(e)[:300]}"
            ) from None
        return state, meta


# --- saved policies ----------------------------------------------------------------------------------
def save_policy(path: Path, config: RunConfig, actor_params, encoder_params, scores: dict) -> None:
    """`path`.msgpack (actor + encoder params) and `path`.json (what they are)."""
    path = Path(path)
    blob = {"actor": jax.device_get(actor_params), "encoder": jax.device_get(encoder_params)}
    atomic.write_bytes(path.with_suffix(".msgpack"), serialization.msgpack_serialize(blob))
    record = {
        "format": POLICY_FORMAT,
        "version": POLICY_VERSION,
        "agent": config.agent,
        "config": config_dict(config),
        "scores": scores,
        "encoder_record": {
            k: v for k, v in enc.load_record(config.encoder and Path(config.encoder)).items() if k != "curve"
        },
    }
    atomic.write_text(path.with_suffix(".json"), json.dumps(record, indent=2) + "\n")


@dataclass(frozen=True)
class Policy:
    config: RunConfig
    actor_params: Any
    encoder_params: Any
    scores: dict


def load_policy(path: Path) -> Policy:
    """A policy saved by `save_policy` (give either file or the stem). Clear errors for missing,
    corrupt or mismatched files."""
    path = Path(path)
    stem = path.with_suffix("") if path.suffix in (".msgpack", ".json") else path
    blob_path, rec_path = stem.with_suffix(".msgpack"), stem.with_suffix(".json")
    for p in (blob_path, rec_path):
        if not p.is_file():
            raise ConfigError(f"policy file not found: {p}")
    try:
        record = json.loads(rec_path.read_text())
    except json.JSONDecodeError as e:
        raise ConfigError(f"policy record {rec_path} is not valid JSON: {e}") from None
    if record.get("format") != POLICY_FORMAT:
        raise ConfigError(f"{rec_path} is not an mjx-push policy record")
    if record.get("version") != POLICY_VERSION:
        raise ConfigError(f"policy {rec_path} has format version {record.get('version')}, expected {POLICY_VERSION}")
    config = config_from_dict(record["config"])
    try:
        blob = serialization.msgpack_restore(blob_path.read_bytes())
    except Exception as e:
        raise ConfigError(f"policy weights {blob_path} are corrupt: {e}") from None
    # Check every array against freshly initialised networks of the recorded agent.
    from train.networks import make_networks

    nets = make_networks(config.train.agent)
    actor_t = jax.eval_shape(lambda: nets.init_actor(jax.random.PRNGKey(0), config.train.loop.episode_len))
    encoder_t = enc._template()
    for name, template in (("actor", actor_t), ("encoder", encoder_t)):
        if name not in blob:
            raise ConfigError(f"policy weights {blob_path} have no {name!r} parameters")
        want = jax.tree.map(lambda s: s.shape, template)
        try:
            got = jax.tree.map(lambda a: np.shape(a), blob[name])
            same = jax.tree.structure(want) == jax.tree.structure(got) and want == got
        except Exception:
            same = False
        if not same:
            raise ConfigError(
                f"policy weights {blob_path}: the {name!r} parameters do not match a {config.agent} network"
            )
    to_jnp = lambda t: jax.tree.map(jnp.asarray, t)  # noqa: E731
    return Policy(config, to_jnp(blob["actor"]), to_jnp(blob["encoder"]), record.get("scores", {}))


# --- metric logs -------------------------------------------------------------------------------------
class MetricLog:
    """metrics.csv + TensorBoard. On resume, rows past the checkpoint are dropped (they will be redone)."""

    def __init__(self, root: Path, resume_env_steps: int | None, write: bool = True):
        from tensorboardX import SummaryWriter

        self.csv_path = root / "metrics.csv"
        self.rows: list[dict] = []
        if resume_env_steps is not None and self.csv_path.is_file():
            with self.csv_path.open() as f:
                self.rows = [r for r in csv.DictReader(f) if float(r["env_steps"]) <= resume_env_steps]
        self.columns: list[str] = list(self.rows[0].keys()) if self.rows else []
        # The other processes of a multi-process run keep their rows in memory only (process 0 writes).
        self.tb = SummaryWriter(str(root / "tb"), purge_step=resume_env_steps) if write else None

    def write(self, metrics: dict) -> None:
        new = [k for k in metrics if k not in self.columns]
        self.columns += new
        self.rows.append(metrics)
        if self.tb is None:
            return
        # Rewritten whole (columns may grow at evaluations), atomically: a kill mid-write keeps the old log.
        out = io.StringIO(newline="")
        w = csv.DictWriter(out, fieldnames=self.columns)
        w.writeheader()
        w.writerows(self.rows)
        atomic.write_text(self.csv_path, out.getvalue())
        step = int(metrics["env_steps"])
        for k, v in metrics.items():
            if k != "env_steps" and isinstance(v, (int, float)) and v == v:
                self.tb.add_scalar(k, v, step)
        self.tb.flush()

    def close(self):
        if self.tb is not None:
            self.tb.close()


# --- the run -----------------------------------------------------------------------------------------
def _barrier(name: str) -> None:
    """Wait for every process of a multi-process run (nothing to wait for in one process)."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


def _check_same_config(run_dir: Path, cfg: RunConfig) -> None:
    saved = load_config(run_dir / "config.json")
    diff = configio.differences(config_dict(saved), config_dict(cfg))
    if diff:
        raise ConfigError(f"--resume: {run_dir} was started with a different configuration: " + "; ".join(diff[:6]))


def prepare_dir(run_dir: Path, cfg: RunConfig, resume: bool, write: bool = True) -> None:
    """Check `run_dir` for a new run or a resume of `cfg`, and (`write`) create it and its config."""
    run_dir = Path(run_dir)
    has_ckpt = any(p.is_dir() and p.name.isdigit() for p in (run_dir / "checkpoints").glob("*"))
    if resume:
        if not has_ckpt:
            raise ConfigError(f"--resume: no checkpoint in {run_dir / 'checkpoints'}")
        _check_same_config(run_dir, cfg)
    else:
        if has_ckpt or (run_dir / "metrics.csv").exists():
            raise ConfigError(
                f"run directory {run_dir} already holds a run; pass --resume to continue it or choose another --run-dir"
            )
        if write:
            run_dir.mkdir(parents=True, exist_ok=True)
            atomic.write_text(run_dir / "config.json", json.dumps(config_dict(cfg), indent=2) + "\n")


class RunFinished(ValueError):
    """`--resume` of a run that has already finished: nothing to do (the message says so)."""


def finished_summary(run_dir: Path, cfg: RunConfig) -> dict | None:
    """The summary of `run_dir` if its run has finished (summary written, last checkpoint at the end)."""
    run_dir = Path(run_dir)
    path = run_dir / "summary.json"
    if not path.is_file():
        return None
    loop = cfg.train.loop
    steps = [int(p.name) for p in (run_dir / "checkpoints").glob("*") if p.is_dir() and p.name.isdigit()]
    if max(steps, default=-1) < loop.num_iterations * loop.env_steps_per_iteration:
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
            "--resume has nothing to continue; train longer in a new --run-dir."
        )


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
) -> tuple[dict, TrainState]:
    """Train `cfg` in `run_dir`. Checkpoints after every `checkpoint_every` batches, at every
    evaluation and at the end. `stop_after`: stop (as if killed) after that many batches of this call.
    `adapter` replaces the MJX task (tests use the toy task). `substep_chunk`: substeps per tick of the
    MJX task's scheduler (0: lockstep; None: the default); it changes speed, not episodes, so it is not
    part of the run's configuration. `stop_on_signal`: SIGINT / SIGTERM stop the run after the current
    batch with a checkpoint (`train.interrupt`); the summary then holds "interrupted_at_env_steps" and
    "signal". One process at a time may run in a directory (`train.run_lock`); resuming a finished run
    raises `RunFinished` and changes nothing. In a multi-process run (`train.data_parallel`) every
    process calls this with the same arguments and directory (a shared file system); process 0 takes
    the lock and writes the logs, policies and summary, all write their shards of each checkpoint.
    Returns (summary, final state)."""
    run_dir = Path(run_dir)
    if resume:
        check_not_finished(run_dir, cfg)
        if not run_dir.is_dir():
            raise ConfigError(f"--resume: no checkpoint in {run_dir / 'checkpoints'} ({run_dir} does not exist)")
    elif data_parallel.is_primary():
        run_dir.mkdir(parents=True, exist_ok=True)
    lock = RunLock(run_dir) if data_parallel.is_primary() else contextlib.nullcontext()
    with lock, StopOnSignal() if stop_on_signal else contextlib.nullcontext() as stop:
        return _run_locked(
            cfg, run_dir, resume, adapter, checkpoint_every, stop_after, on_iteration, substep_chunk, stop
        )


def _run_locked(cfg, run_dir, resume, adapter, checkpoint_every, stop_after, on_iteration, substep_chunk, stop):
    primary = data_parallel.is_primary()
    # Every process checks (what process 0 writes here, the config, none of the checks reads); the
    # others wait for the directory before they open its checkpoints.
    prepare_dir(run_dir, cfg, resume, write=primary)
    _barrier("prepared the run directory")
    encoder_params = enc.load(cfg.encoder and Path(cfg.encoder))
    loop = cfg.train.loop
    if adapter is None:
        from train.push_task import DEFAULT_SUBSTEP_CHUNK, make_push_adapter

        chunk = DEFAULT_SUBSTEP_CHUNK if substep_chunk is None else substep_chunk
        # Data parallel: each device steps its own environments (no split of a batch over devices).
        max_devices = 1 if loop.data_parallel > 1 else None
        adapter = make_push_adapter(cfg.env, encoder_params, chunk, cfg.expert, max_devices=max_devices)
    trainer = make_train(cfg.train, adapter)
    runner = Runner(trainer)
    ckpts = Checkpoints(run_dir / "checkpoints")
    state = runner.init(jax.random.PRNGKey(loop.seed))
    resumed_from = None
    if resume:
        state, meta = ckpts.restore(state, cfg)
        resumed_from = int(state.env_steps)
    log = MetricLog(run_dir, resumed_from, write=primary)

    t_start = time.perf_counter()
    clock = {"last": t_start, "first": None, "done": 0}

    def on_batch(ts: TrainState, metrics: dict) -> bool:
        """After each batch (and its evaluation): timing, logs, checkpoints; True stops the run."""
        now = time.perf_counter()
        dt, clock["last"] = now - clock["last"], now
        clock["first"] = dt if clock["first"] is None else clock["first"]
        metrics["wall_s"] = now - t_start
        metrics["iteration_s"] = dt
        metrics["env_steps_per_s"] = loop.env_steps_per_iteration / dt
        metrics["updates_per_s"] = (loop.updates_per_iteration / dt) if metrics["learning"] else 0.0
        log.write(metrics)
        if on_iteration is not None and primary:
            on_iteration(metrics)
        clock["done"] += 1
        i = int(ts.env_steps) // loop.env_steps_per_iteration - 1
        last = i == loop.num_iterations - 1
        interrupted = stop is not None and stop.requested is not None
        if last or interrupted or "eval/mean_reward" in metrics or (i + 1) % checkpoint_every == 0:
            ckpts.save(ts, cfg, {"history_rows": len(log.rows)})
        return (interrupted or (stop_after is not None and clock["done"] >= stop_after)) and not last

    try:
        state, _ = train_loop(None, cfg.train, adapter, callback=on_batch, state=state, runner=runner)
    finally:
        log.close()
    if int(state.env_steps) < loop.num_iterations * loop.env_steps_per_iteration:
        stopped = {"stopped_at_env_steps": int(state.env_steps)}
        if stop is not None and stop.requested is not None:
            stopped.update(interrupted_at_env_steps=int(state.env_steps), signal=stop.requested)
        return stopped, state
    first_call_s = clock["first"]

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
        "wall_s": time.perf_counter() - t_start,
        "first_batch_s": first_call_s,
        "steady_env_steps_per_s": (loop.env_steps_per_iteration / np.mean(steady)) if steady else None,
        "resumed_from_env_steps": resumed_from,
        "run_dir": str(run_dir),
    }
    atomic.write_text(run_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary, state

"""Orbax checkpoints of a whole TrainState (params, optimiser states, replay buffer, RNG key, counters,
best params), keyed by environment steps, each with a JSON record of the run's configuration: what a
run needs to resume exactly (train/runs/run.py)."""

from __future__ import annotations

import dataclasses
import shutil
import warnings
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp

from mjx_push.train import configio
from mjx_push.train.loop import TrainState
from mjx_push.train.config import RunConfig
from mjx_push.train.presets import config_dict, config_from_dict
from mjx_push.errors import ConfigError

CHECKPOINT_FORMAT = "mjx-push-checkpoint"
CHECKPOINT_VERSION = 1
# TrainState fields added since checkpoints of this version were first written. A checkpoint without
# them restores the rest and takes their initial value from the template: what the run held, since
# they only change where a later feature is switched on, and no saved configuration could switch it on.
ADDED_FIELDS = ("anchor_actor_params",)


def saved_steps(directory: Path) -> list[int]:
    """The env steps of the complete checkpoints in `directory`, ascending, read from the folder names
    alone (nothing opened; an unfinished write is a temporary folder and does not count)."""
    return sorted(int(p.name) for p in Path(directory).glob("*") if p.is_dir() and p.name.isdigit())


def placed_like(state: TrainState, template: TrainState) -> TrainState:
    """`state` with each array placed as the template's is. Orbax returns arrays committed to their
    device; a fresh run's are uncommitted (jit places them). A program traced for committed arguments
    is another program: a resumed run whose functions take the state as it comes (one device and no
    rollout split: a GPU, the toy task) compiled its rollout and learner anew, with the run's own
    programs in the compilation cache (a fork too, where its changes leave the programs alone). A
    data-parallel run's template is committed to its mesh and its restored arrays stay as they are."""

    def put(x, t):
        if isinstance(x, jax.Array) and isinstance(t, jax.Array) and x.committed and not t.committed:
            return jax.device_put(np.asarray(x))  # from host memory: uncommitted, on the default device
        return x

    return jax.tree.map(put, state, template)


class Checkpoints:
    """Orbax checkpoints of a TrainState, keyed by environment steps, the last `keep` kept."""

    def __init__(self, directory: Path, keep: int = 2, read_only: bool = False):
        """`read_only`: only read (a fork's source, which may be training): its unfinished writes stay."""
        self.directory = Path(directory).absolute()
        # A checkpoint is written into a temporary directory and renamed when complete, so a kill mid-write
        # leaves the previous checkpoint as the latest; such leftovers are removed here, before the manager
        # starts. (Orbax's own cleanup runs in a background thread: two managers of one directory in a
        # process, e.g. a check of the latest step and then a resume, raced to delete the same folder.)
        for leftover in () if read_only else self.directory.glob("*.orbax-checkpoint-tmp*"):
            shutil.rmtree(leftover, ignore_errors=True)
        options = ocp.CheckpointManagerOptions(
            max_to_keep=keep, enable_async_checkpointing=False, create=True, cleanup_tmp_directories=False
        )
        # Handlers named up front, so a checkpoint's tree metadata can be read before anything is restored.
        handlers = {"state": ocp.StandardCheckpointHandler(), "meta": ocp.JsonCheckpointHandler()}
        self.manager = ocp.CheckpointManager(self.directory, options=options, item_handlers=handlers)

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
        mine = config_dict(config)
        # A run trained longer (`mjx_push.train.runs.run.run`) restores the checkpoints of its shorter self.
        diff = [] if configio.trained_longer(saved, mine) else configio.differences(saved, mine)
        if diff:
            raise ConfigError(
                f"checkpoint {self.directory}/{step} was made with a different configuration: " + "; ".join(diff[:6])
            )
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, template)
        mismatched = self._mismatched_arrays(step, abstract)
        if mismatched:  # refused before any read: a restore failing half way leaves orbax's other reads pending
            raise ConfigError(
                f"checkpoint {self.directory}/{step} does not match this run's state (shapes, dtypes or "
                f"structure): {'; '.join(mismatched[:4])}"
                + (f" and {len(mismatched) - 4} more" if len(mismatched) > 4 else "")
            )
        try:
            state = self.manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))[
                "state"
            ]
        except Exception as e:
            # Only a checkpoint that lacks a field added since may fall back; any other mismatch (a
            # field present but of another shape, a garbled array) is an error, never a silent default.
            missing = self._missing_added_fields(step)
            state = self._restore_without(missing, step, template, abstract) if missing else None
            if state is not None:
                warnings.warn(
                    f"checkpoint {self.directory}/{step} was written before TrainState had "
                    f"{', '.join(missing)}; restored the rest and took {'it' if len(missing) == 1 else 'them'} "
                    "from the run's initial state",
                    stacklevel=2,
                )
                return placed_like(state, template), meta
            raise ConfigError(
                f"checkpoint {self.directory}/{step} is corrupt or does not match this run's "
                f"state (shapes, dtypes or structure): {type(e).__name__}: {str(e)[:300]}"
            ) from None
        return placed_like(state, template), meta

    def _mismatched_arrays(self, step: int, abstract: TrainState) -> list[str]:
        """The arrays the checkpoint at `step` holds at a path of `abstract` with another shape or dtype,
        each as "path: saved DTYPE[SHAPE], this run's DTYPE[SHAPE]", read from its tree metadata; [] when
        the metadata cannot be read. Paths only one side has are left to the restore (added fields)."""
        tree = self._saved_tree(step)
        if tree is None:
            return []
        saved = {_path_name(p): leaf for p, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]}
        out = []
        for p, leaf in jax.tree_util.tree_flatten_with_path(abstract)[0]:
            name = _path_name(p)
            meta = saved.get(name)
            if meta is None or not (hasattr(meta, "shape") and hasattr(meta, "dtype")):
                continue
            try:
                was, now = (np.dtype(meta.dtype), tuple(meta.shape)), (np.dtype(leaf.dtype), tuple(leaf.shape))
            except TypeError:  # a dtype NumPy does not know (typed PRNG keys): left to the restore
                continue
            if was != now:
                out.append(f"{name}: saved {was[0]}{list(was[1])}, this run's {now[0]}{list(now[1])}")
        return out

    def _missing_added_fields(self, step: int) -> tuple[str, ...]:
        """Which of `ADDED_FIELDS` the checkpoint at `step` does not hold, read from its tree metadata
        (nothing restored); () when the metadata cannot be read."""
        tree = self._saved_tree(step)
        if not isinstance(tree, dict):
            return ()
        return tuple(name for name in ADDED_FIELDS if name not in tree)

    def _saved_tree(self, step: int):
        """The state's tree metadata of the checkpoint at `step` (each array's shape and dtype, nothing
        read), or None when it cannot be read."""
        try:
            return self.manager.item_metadata(step)["state"].tree
        except Exception:
            return None

    def _restore_without(
        self, missing: tuple[str, ...], step: int, template: TrainState, abstract: TrainState
    ) -> TrainState | None:
        """The checkpoint at `step` read without the `missing` fields, those from `template`; None when
        the rest does not match either."""
        older = {f.name: getattr(abstract, f.name) for f in dataclasses.fields(template) if f.name not in missing}
        try:
            got = self.manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(older)))["state"]
        except Exception:
            return None
        return template.replace(**got)


def _path_name(path) -> str:
    """A pytree key path as "field/key/index", the same for a TrainState and its checkpoint's metadata."""
    return jax.tree_util.keystr(path, simple=True, separator="/")

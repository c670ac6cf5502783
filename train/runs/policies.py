"""Saved policies of a run: ``<stem>.msgpack`` (actor and encoder params) beside ``<stem>.json`` (the
agent, the whole configuration, its evaluation scores, the encoder's record), written atomically and
read back against freshly initialised networks of the recorded agent."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from mjx_push import encoder as enc
from mjx_push.train.runs import atomic
from mjx_push.train.config import RunConfig
from mjx_push.train.presets import config_dict, config_from_dict
from mjx_push.errors import ConfigError

POLICY_FORMAT = "mjx-push-policy"
POLICY_VERSION = 1


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
    from mjx_push.train.networks import make_networks

    nets = make_networks(config.train.agent)
    actor_t = jax.eval_shape(lambda: nets.init_actor(jax.random.PRNGKey(0), config.env.episode_length))
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

"""The exported policy file: one `.npz` of float32 weights plus a JSON metadata record inside it.

    export_policy(mjx_push.train.runs.policies.load_policy("runs/egru/best_policy"), Path("egru.npz"))   # needs jax (training side)
    pf = load_npz("egru.npz")                                                       # NumPy only

Arrays, named by their flax parameter paths (kernels are flax layouts: Dense (in, out), Conv HWIO):
- "encoder/Conv_{0..3}/{kernel,bias}", "encoder/Dense_0/{kernel,bias}", "encoder/mean/{kernel,bias}": the
  mask encoder's mean path (the log-variance head is only used while training the VAE and is left out);
- "actor/mlp/Dense_{i}/{kernel,bias}", "actor/mean_head/{kernel,bias}", "actor/log_std_head/{kernel,bias}";
- GRU agents also "actor/features/cell/{ir,iz,in}/{kernel,bias}", "actor/features/cell/{hr,hz}/kernel",
  "actor/features/cell/hn/{kernel,bias}" (flax GRUCell; the equations are in the metadata).
- agents trained with input normalisation (metadata ``agent.obs_norm`` = {"clip": c}) also
  "actor/norm/{ee_xy,z}_{mean,std}": the actor first maps ee_xy to clip((ee_xy - mean) / std, -c, c), and
  z_obj and z_goal alike with the z statistics.
- "__metadata__": the UTF-8 bytes (uint8) of the JSON record: format and version, agent, observation
  layout, action mapping, camera and mask convention, encoder architecture and record, package version,
  training scores and the full run configuration.

A file may leave the encoder out and reference the one the package ships instead (``export_policy(...,
encoder="package")``; metadata ``encoder.weights`` = {"source": "package", "sha256": ...}): the shipped
policies (`mjx_push.export.pretrained`) do, since the encoder is nearly all of a file's 4 MB. Loading such a file
reads the package's encoder (msgpack, read here with NumPy) and refuses it if its sha256 differs.

`load_npz` checks everything a reader relies on (format, version, every array's presence, shape, dtype and
finiteness against the shapes the metadata implies) and raises ValueError naming the file and the problem.
`load_as_policy` turns a file back into a `mjx_push.train.runs.policies.Policy` (for `mjx-push eval` on the MJX scene).
This module imports only NumPy when loading; `export_policy` and `load_as_policy` import the training
side lazily.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mjx_push.errors import ConfigError

FORMAT = "mjx-push-numpy-policy"
FORMAT_VERSION = 1
METADATA_KEY = "__metadata__"
ENCODER_SOURCES = ("embed", "package")  # the encoder's weights: in the file, or the package's (by hash)
AGENT_KINDS = ("vpm", "stacked", "ugru", "egru")
GRU_GATES_IN = ("ir", "iz", "in")  # input-side Dense layers (with bias)
GRU_GATES_H = ("hr", "hz", "hn")  # hidden-side Dense layers (only hn has a bias)
GRU_EQUATIONS = (
    "flax.linen.GRUCell: r = sigmoid(x @ ir.kernel + ir.bias + h @ hr.kernel); "
    "z = sigmoid(x @ iz.kernel + iz.bias + h @ hz.kernel); "
    "n = tanh(x @ in.kernel + in.bias + r * (h @ hn.kernel + hn.bias)); h' = (1 - z) * n + z * h; h0 = 0"
)
SUBSTEPS_FORMULA = (
    "n = clip(floor(low + (clip(a_s, -1, 1) + 1) * 0.5 * (high - low)), low, high), evaluated in float32 "
    "(mjx_push.env.decode_substeps)"
)


@dataclass(frozen=True)
class PolicyFile:
    """A loaded and validated policy file."""

    path: Path
    metadata: dict
    arrays: dict[str, np.ndarray]

    @property
    def kind(self) -> str:
        return self.metadata["agent"]["kind"]


# --- shapes the metadata implies ---------------------------------------------------------------------
def _pos_int(meta_field: str, v) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
        raise ConfigError(f"metadata field {meta_field} must be a positive integer, got {v!r}")
    return v


def feature_dim(meta: dict) -> int:
    """Width of the feature extractor's output (the actor MLP's input)."""
    agent = meta["agent"]
    obs_dim = _pos_int("observation.obs_dim", meta["observation"]["obs_dim"])
    if agent["kind"] == "vpm":
        return obs_dim
    if agent["kind"] == "stacked":
        return _pos_int("agent.stack", agent["stack"]) * obs_dim
    return _pos_int("agent.gru_hidden", agent["gru_hidden"])


def expected_shapes(meta: dict) -> dict[str, tuple[int, ...]]:
    """Every array name -> shape, from the architecture recorded in the metadata."""
    try:
        return _expected_shapes(meta)
    except (KeyError, TypeError, IndexError) as e:
        raise ConfigError(f"metadata is missing or has a malformed field ({type(e).__name__}: {e})") from None


def _expected_shapes(meta: dict) -> dict[str, tuple[int, ...]]:
    enc, agent = meta["encoder"], meta["agent"]
    if agent["kind"] not in AGENT_KINDS:
        raise ConfigError(f"metadata field agent.kind must be one of {AGENT_KINDS}, got {agent['kind']!r}")
    shapes: dict[str, tuple[int, ...]] = {}
    k, stride = _pos_int("encoder.kernel", enc["kernel"]), _pos_int("encoder.stride", enc["stride"])
    n = _pos_int("camera.image_size", meta["camera"]["image_size"])
    c_in = 1
    for i, c in enumerate(enc["channels"]):
        c = _pos_int(f"encoder.channels[{i}]", c)
        shapes[f"encoder/Conv_{i}/kernel"] = (k, k, c_in, c)
        shapes[f"encoder/Conv_{i}/bias"] = (c,)
        n = (n - k) // stride + 1  # VALID padding
        if n < 1:
            raise ConfigError("metadata encoder convolutions shrink the image to nothing")
        c_in = c
    dense, latent = _pos_int("encoder.dense", enc["dense"]), _pos_int("encoder.latent_dim", enc["latent_dim"])
    shapes["encoder/Dense_0/kernel"] = (n * n * c_in, dense)
    shapes["encoder/Dense_0/bias"] = (dense,)
    shapes["encoder/mean/kernel"] = (dense, latent)
    shapes["encoder/mean/bias"] = (latent,)

    obs_dim = _pos_int("observation.obs_dim", meta["observation"]["obs_dim"])
    if obs_dim != 2 + 2 * latent:
        raise ConfigError(f"metadata observation.obs_dim must be 2 + 2 * latent_dim = {2 + 2 * latent}, got {obs_dim}")
    if agent["kind"] in ("ugru", "egru"):
        h = _pos_int("agent.gru_hidden", agent["gru_hidden"])
        for g in GRU_GATES_IN:
            shapes[f"actor/features/cell/{g}/kernel"] = (obs_dim, h)
            shapes[f"actor/features/cell/{g}/bias"] = (h,)
        for g in GRU_GATES_H:
            shapes[f"actor/features/cell/{g}/kernel"] = (h, h)
        shapes["actor/features/cell/hn/bias"] = (h,)
    if agent.get("obs_norm"):
        for group, dim in (("ee_xy", 2), ("z", latent)):
            for what in ("mean", "std"):
                shapes[f"actor/norm/{group}_{what}"] = (dim,)
    width = feature_dim(meta)
    for i, h in enumerate(agent["hidden"]):
        h = _pos_int(f"agent.hidden[{i}]", h)
        shapes[f"actor/mlp/Dense_{i}/kernel"] = (width, h)
        shapes[f"actor/mlp/Dense_{i}/bias"] = (h,)
        width = h
    if not agent["hidden"]:
        raise ConfigError("metadata field agent.hidden must not be empty")
    a = _pos_int("action.dim", meta["action"]["dim"])
    for head in ("mean_head", "log_std_head"):
        shapes[f"actor/{head}/kernel"] = (width, a)
        shapes[f"actor/{head}/bias"] = (a,)
    return shapes


# --- loading -----------------------------------------------------------------------------------------
def load_npz(path: Path | str) -> PolicyFile:
    """Read and validate a policy file written by `export_policy`."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"policy file not found: {path}")
    if not zipfile.is_zipfile(path):
        raise ConfigError(f"policy file {path} is not an .npz (zip) archive: truncated, corrupt or another format")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files}
    except Exception as e:  # zipfile, zlib and numpy raise unrelated types on damaged members
        raise ConfigError(f"policy file {path} is corrupt (an array cannot be read: {type(e).__name__}: {e})") from None
    meta = _read_metadata(path, arrays.pop(METADATA_KEY, None))
    if _encoder_source(meta, path) == "package":
        if any(name.startswith("encoder/") for name in arrays):
            raise ConfigError(f"policy file {path} references the package's encoder but also holds encoder arrays")
        arrays.update(package_encoder_arrays(meta["encoder"]["weights"].get("sha256"), path))
    try:
        want = expected_shapes(meta)
    except ValueError as e:
        raise ConfigError(f"policy file {path}: {e}") from None
    missing = sorted(set(want) - set(arrays))
    if missing:
        raise ConfigError(
            f"policy file {path} lacks {len(missing)} array(s) its {meta['agent']['kind']} metadata "
            f"requires: {missing[:5]}"
        )
    unexpected = sorted(set(arrays) - set(want))
    if unexpected:
        raise ConfigError(f"policy file {path} has arrays its metadata does not describe: {unexpected[:5]}")
    for name, shape in want.items():
        a = arrays[name]
        if a.shape != shape:
            raise ConfigError(f"policy file {path}: array {name!r} has shape {a.shape}, the metadata implies {shape}")
        if a.dtype != np.float32:
            raise ConfigError(f"policy file {path}: array {name!r} has dtype {a.dtype}, expected float32")
        if not np.all(np.isfinite(a)):
            raise ConfigError(f"policy file {path}: array {name!r} holds non-finite values")
        if name.startswith("actor/norm/") and name.endswith("_std") and not np.all(a > 0):
            raise ConfigError(f"policy file {path}: normalisation {name!r} must be positive")
    clip = (meta["agent"].get("obs_norm") or {}).get("clip", 1.0)
    if not (isinstance(clip, (int, float)) and math.isfinite(clip) and clip > 0):
        raise ConfigError(
            f"policy file {path}: metadata field agent.obs_norm.clip must be a positive number, got {clip!r}"
        )
    return PolicyFile(path, meta, arrays)


def _read_metadata(path: Path, raw: np.ndarray | None) -> dict:
    if raw is None:
        raise ConfigError(f"policy file {path} has no {METADATA_KEY!r} record: not an mjx-push policy export")
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise ConfigError(f"policy file {path}: {METADATA_KEY!r} must be a 1-D uint8 array of JSON bytes")
    try:
        meta = json.loads(raw.tobytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ConfigError(f"policy file {path}: the metadata record is not valid JSON ({e})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise ConfigError(f"policy file {path} is not an mjx-push NumPy policy (format {got!r}, expected {FORMAT!r})")
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise ConfigError(
            f"policy file {path} has format version {version!r}; this reader understands version "
            f"{FORMAT_VERSION} only (re-export the policy with a matching mjx-push)"
        )
    return meta


def _encoder_source(meta: dict, path: Path) -> str:
    weights = (meta.get("encoder") or {}).get("weights") or {"source": "embed"}
    source = weights.get("source") if isinstance(weights, dict) else None
    if source not in ENCODER_SOURCES:
        raise ConfigError(
            f"policy file {path}: metadata field encoder.weights.source must be one of "
            f"{ENCODER_SOURCES}, got {source!r}"
        )
    return source


# --- the package's encoder, read without JAX ---------------------------------------------------------
def package_encoder_path() -> Path:
    """The encoder weights mjx_push ships (found without importing mjx_push, which starts JAX)."""
    spec = importlib.util.find_spec("mjx_push")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError(
            "the mjx_push package is not installed: a policy file that references its encoder "
            "needs it (or re-export the policy with the encoder embedded)"
        )
    return Path(list(spec.submodule_search_locations)[0]) / "assets" / "encoder.msgpack"


def package_encoder_sha256() -> str:
    return hashlib.sha256(package_encoder_path().read_bytes()).hexdigest()


def _read_flax_msgpack(blob: bytes) -> dict:
    """A flax `msgpack_serialize` blob of plain arrays -> nested dict of NumPy arrays (flax writes each
    array as msgpack extension type 1 holding (shape, dtype name, C-order bytes))."""
    import msgpack

    def ext(code, data):
        if code != 1:
            raise ConfigError(f"unsupported msgpack extension type {code}")
        shape, dtype, buf = msgpack.unpackb(data, raw=True)
        return np.frombuffer(buf, dtype=np.dtype(dtype.decode())).reshape(shape)

    return msgpack.unpackb(blob, ext_hook=ext, raw=False, strict_map_key=False)


def package_encoder_arrays(sha256: str | None, path: Path | str = "policy") -> dict[str, np.ndarray]:
    """The package encoder's mean path as export arrays ("encoder/..."), after checking that its sha256
    is the one a policy file recorded."""
    enc_path = package_encoder_path()
    blob = enc_path.read_bytes()
    have = hashlib.sha256(blob).hexdigest()
    if sha256 != have:
        raise ConfigError(
            f"policy file {path} was exported against the package encoder with sha256 {sha256}, "
            f"but this mjx-push ships {have} ({enc_path}): use the mjx-push version it was "
            "exported with, or re-export it with the encoder embedded"
        )
    tree = _read_flax_msgpack(blob)
    return _flatten({k: v for k, v in tree.items() if k != "logvar"}, "encoder")


# --- writing (training side) -------------------------------------------------------------------------
def _flatten(tree: Any, prefix: str) -> dict[str, np.ndarray]:
    out = {}
    for key, value in tree.items():
        name = f"{prefix}/{key}"
        if isinstance(value, dict) or hasattr(value, "items"):
            out.update(_flatten(value, name))
        else:
            out[name] = np.asarray(value, dtype=np.float32)
    return out


def _json_safe(x):
    """NaN / inf scores become null: the record must be strict JSON for non-Python readers."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return _json_safe(x.item())
    return x


def _pixel_convention() -> str:
    from mjx_push import mask_geometry

    doc = mask_geometry.__doc__ or ""
    start = doc.find("Pixel convention")
    para = doc[start:].split("\n\n")[0] if start >= 0 else ""
    return " ".join(para.split())


def build_metadata(policy, provenance: dict | None = None) -> dict:
    """The JSON record for a `mjx_push.train.runs.policies.Policy`; ``provenance`` (e.g. the run directory and the commit
    that trained it) is recorded as given."""
    from importlib.metadata import PackageNotFoundError, version

    from mjx_push import encoder as enc
    from mjx_push import scene
    from mjx_push.train import configio
    from mjx_push.train.networks import ACTION_DIM, LOG_STD_MAX, LOG_STD_MIN, OBS_DIM

    cfg = policy.config
    agent, env = cfg.train.agent, cfg.env
    try:
        pkg_version = version("mjx-push")
    except PackageNotFoundError:
        pkg_version = None
    record = enc.load_record(cfg.encoder and Path(cfg.encoder))
    return _json_safe(
        {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "package_version": pkg_version,
            "agent": {
                "kind": agent.kind,
                "hidden": list(agent.hidden),
                "gru_hidden": agent.gru_hidden,
                "stack": agent.stack,
                "mlp_activation": "relu",
                "log_std_clip": [LOG_STD_MIN, LOG_STD_MAX],
                "gru_equations": GRU_EQUATIONS if agent.recurrent else None,
                "obs_norm": {"clip": agent.norm_clip} if agent.obs_norm else None,
            },
            "observation": {
                "obs_dim": OBS_DIM,
                "per_step": {"ee_xy": 2, "z_obj": enc.LATENT_DIM, "z_goal": enc.LATENT_DIM},
                "flat_order": ["ee_xy", "z_obj", "z_goal"],
                "gru_input_order": ["z_obj", "z_goal", "ee_xy"],
                "stack": agent.stack,
                "stack_order": "oldest first, flattened; zeros stand in for the steps before the first observation",
                "first_step": "the observation at reset is the first step of the history",
                "ee_xy": "measured flange xy in the robot base frame, metres",
                "obs_noise_std": env.obs_noise,
                "z_obj": "encoder mean of the current object mask",
                "z_goal": "encoder mean of the goal mask (constant over an episode)",
                "normalisation": (
                    "before the feature extractor: ee_xy -> clip((ee_xy - actor/norm/ee_xy_mean) / "
                    "actor/norm/ee_xy_std, -clip, clip), z_obj and z_goal likewise with actor/norm/z_*"
                    if agent.obs_norm
                    else None
                ),
            },
            "action": {
                "dim": ACTION_DIM,
                "components": ["a_x", "a_y", "a_s"],
                "range": [-1.0, 1.0],
                "deterministic": "tanh(mean_head(h))",
                "stochastic": "tanh(mean + exp(clip(log_std)) * N(0, 1))",
                "action_scale": env.action_scale,
                "target": "flange target = (clip(ee_x + a_x * action_scale, workspace_x), clip(ee_y + a_y * "
                "action_scale, workspace_y), home_flange_z)",
                "workspace_x": list(env.workspace_x),
                "workspace_y": list(env.workspace_y),
                "home_flange_z": float(scene.home_flange_pos()[2]),
                "substeps": list(env.substeps),
                "substeps_formula": SUBSTEPS_FORMULA,
                "substep_seconds": 0.001,
                "sanitize": "non-finite components become 0, the rest are clipped to [-1, 1]",
                "controller_gain": env.controller.gain,
                "controller": "task-space velocity law dq = gain * J^+ e at every 1 ms substep (run_config.env.controller)",
            },
            "camera": {
                "name": "under_table",
                "image_size": scene.IMAGE_SIZE,
                "fovy_deg": scene.CAMERA_FOVY,
                "pos": [float(v) for v in scene.CAMERA_POS],
                "direction": "looking straight up (+z)",
                "pixel_convention": _pixel_convention(),
                "mask": "bool (64, 64), True on the object's silhouette; fed to the encoder as float32 0/1",
            },
            "encoder": {
                "channels": list(enc.CHANNELS),
                "kernel": 4,
                "stride": 2,
                "padding": "VALID",
                "activation": "relu",
                "dense": enc.DENSE,
                "latent_dim": enc.LATENT_DIM,
                "layout": "input NHWC (1 channel); Conv kernels HWIO; flatten row-major over (h, w, c)",
                "record": {k: v for k, v in record.items() if k != "curve"},
            },
            "task": {"episode_length": env.episode_length, "success_tau": env.success_tau},
            "scores": dict(policy.scores),
            "provenance": dict(provenance or {}),
            "run_config": configio.to_dict(cfg),
        }
    )


def _unflatten(arrays: dict[str, np.ndarray], prefix: str) -> dict:
    tree: dict = {}
    for name, value in arrays.items():
        if not name.startswith(prefix + "/"):
            continue
        node = tree
        *parents, leaf = name[len(prefix) + 1 :].split("/")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return tree


def load_as_policy(path: Path | str):
    """An exported .npz back as a `mjx_push.train.runs.policies.Policy` (JAX arrays), e.g. to evaluate it on the MJX scene.
    The encoder's log-variance head is not exported (only the mean is ever used by a policy): it comes
    back as zeros so the flax encoder's parameter tree is complete."""
    import jax
    import jax.numpy as jnp

    from mjx_push.train.runs.policies import Policy
    from mjx_push.train.presets import config_from_dict

    pf = load_npz(path)
    try:
        config = config_from_dict(pf.metadata["run_config"])
    except (KeyError, ValueError) as e:
        raise ConfigError(f"policy file {pf.path}: its run configuration does not fit this mjx-push ({e})") from None
    if config.agent != pf.kind:
        raise ConfigError(f"policy file {pf.path}: run configuration agent {config.agent!r} != metadata {pf.kind!r}")
    encoder = _unflatten(pf.arrays, "encoder")
    dense, latent = pf.metadata["encoder"]["dense"], pf.metadata["encoder"]["latent_dim"]
    encoder["logvar"] = {"kernel": np.zeros((dense, latent), np.float32), "bias": np.zeros(latent, np.float32)}
    tree = _unflatten(pf.arrays, "actor")
    norm = tree.pop("norm", None)
    actor = {"params": jax.tree.map(jnp.asarray, tree)}
    if norm is not None:
        actor["norm"] = {"norm": jax.tree.map(jnp.asarray, norm)}
    return Policy(config, actor, jax.tree.map(jnp.asarray, encoder), dict(pf.metadata.get("scores", {})))


def export_policy(policy, out: Path | str, encoder: str = "embed", provenance: dict | None = None) -> dict:
    """Write `policy` (a `mjx_push.train.runs.policies.Policy`) to the .npz `out`; returns the metadata written.
    ``encoder`` "package" leaves the encoder out and records the package encoder's sha256 instead (the
    policy must have been trained with that encoder: checked, array by array)."""
    out = Path(out)
    if out.suffix != ".npz":
        raise ConfigError(f"out must be an .npz path, got {out}")
    if encoder not in ENCODER_SOURCES:
        raise ConfigError(f"encoder must be one of {ENCODER_SOURCES}, got {encoder!r}")
    meta = build_metadata(policy, provenance)
    arrays = _flatten(policy.actor_params["params"], "actor")
    if "norm" in policy.actor_params:
        arrays.update(_flatten(policy.actor_params["norm"]["norm"], "actor/norm"))
    encoder_arrays = _flatten({k: v for k, v in policy.encoder_params.items() if k != "logvar"}, "encoder")
    arrays.update(encoder_arrays)
    want = expected_shapes(meta)
    got = {k: v.shape for k, v in arrays.items()}
    if got != want:  # the networks changed without this format following: fail here, not in a reader
        raise ConfigError(
            f"policy parameters do not match export format {FORMAT_VERSION}: "
            f"missing {sorted(set(want) - set(got))[:4]}, unexpected {sorted(set(got) - set(want))[:4]}, "
            f"wrong shapes {[k for k in set(want) & set(got) if want[k] != got[k]][:4]}"
        )
    if encoder == "package":
        sha = package_encoder_sha256()
        shipped = package_encoder_arrays(sha)
        if any(not np.array_equal(shipped[k], v) for k, v in encoder_arrays.items()):
            raise ConfigError(
                "encoder='package': this policy's encoder is not the one the package ships; "
                "export it with the encoder embedded"
            )
        meta["encoder"]["weights"] = {"source": "package", "sha256": sha}
        arrays = {k: v for k, v in arrays.items() if k not in encoder_arrays}
    else:
        meta["encoder"]["weights"] = {"source": "embed"}
    arrays[METADATA_KEY] = np.frombuffer(json.dumps(meta, indent=1).encode("utf-8"), dtype=np.uint8)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".partial")
    with open(tmp, "wb") as f:  # a file object: np.savez would otherwise append ".npz" to the name
        np.savez(f, **arrays)
    os.replace(tmp, out)  # never leave a half-written policy under the final name
    return meta

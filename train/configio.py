"""Typed configs to and from JSON-able dicts (run records, checkpoints, exported policies).

`from_dict` rebuilds nested frozen dataclasses from their field types, turns JSON lists back into the
tuples the configs hold, and rejects unknown or missing fields by name, so a record written by another
version fails loudly instead of silently training something else.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from typing import Any
from mjx_push.errors import ConfigError


def to_dict(obj) -> dict:
    """JSON-normalised (tuples become lists), so a dict read back from disk compares equal."""
    return json.loads(json.dumps(dataclasses.asdict(obj)))


def _convert(tp, value, where: str):
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        return from_dict(tp, value, where)
    if tp is tuple or origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        return tuple(value)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        if value is None:
            return None
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        return _convert(inner[0], value, where) if len(inner) == 1 else value
    if origin is typing.Literal and value not in typing.get_args(tp):
        raise ConfigError(f"{where} must be one of {list(typing.get_args(tp))}, got {value!r}")
    # A value of the wrong kind (e.g. `--set train.sac.lr=abc`) is named here, not met as a TypeError
    # deep in a config's checks. bool is an int in Python, but never a number of a config.
    if tp in _KINDS and (not isinstance(value, _KINDS[tp][0]) or (tp is not bool and isinstance(value, bool))):
        raise ConfigError(f"{where} must be {_KINDS[tp][1]}, got {value!r}")
    return float(value) if tp is float else value  # `--set x=2` gives 2.0, as the config file will say


_KINDS = {
    float: ((int, float), "a number"),
    int: (int, "an integer"),
    bool: (bool, "true or false"),
    str: (str, "a string"),
}


def from_dict(cls, data: Any, where: str = ""):
    """Rebuild dataclass `cls` from `data` (as written by `to_dict`)."""
    name = where or cls.__name__
    if not isinstance(data, dict):
        raise ConfigError(f"{name} must be a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{name} has unknown fields {unknown}")
    kwargs = {}
    for key, f in fields.items():
        if key not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{name} is missing the field {key!r}")
            continue
        kwargs[key] = _convert(hints[key], data[key], f"{name}.{key}")
    return cls(**kwargs)


def trained_longer(saved: dict, new: dict) -> bool:
    """True when config dict `new` is `saved` with a larger ``train.loop.total_env_steps`` and nothing
    else changed: the same run trained for more env steps (`mjx_push.train.runs.run.run` continues it)."""
    try:
        old_total, new_total = (d["train"]["loop"]["total_env_steps"] for d in (saved, new))
    except (KeyError, TypeError):
        return False
    same = json.loads(json.dumps(saved))  # a deep copy of plain data
    same["train"]["loop"]["total_env_steps"] = new_total
    return new_total > old_total and not differences(same, new)


def differences(a: dict, b: dict, prefix: str = "") -> list[str]:
    """Dotted paths where two config dicts differ (for 'checkpoint does not match this run')."""
    out = []
    for k in sorted(set(a) | set(b)):
        path = f"{prefix}{k}"
        va, vb = a.get(k, "<missing>"), b.get(k, "<missing>")
        if isinstance(va, dict) and isinstance(vb, dict):
            out += differences(va, vb, path + ".")
        elif va != vb:
            out.append(f"{path}: {va!r} != {vb!r}")
    return out

"""Nested config dataclasses from plain mappings (dicts, Hydra's ``DictConfig``, YAML data).

``build(SimConfig, {"terrain": {...}, "data": {...}})`` starts from the dataclass's defaults
and merges what the mapping gives over them, recursing into nested dataclasses (a nested
mapping edits the default value, as a Hydra merge does); an unknown key raises ``ValueError``
naming it. Any mapping works, so the simulator reads Hydra configs without importing OmegaConf.
"""

from __future__ import annotations

import copy
import dataclasses
import typing
from collections.abc import Mapping, Sequence


def _is_mapping(value) -> bool:
    return isinstance(value, Mapping) or (hasattr(value, "keys") and hasattr(value, "__getitem__") and not isinstance(value, (str, bytes)))


def _convert(value, kind, current, key: str):
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return copy.deepcopy(value)
    if dataclasses.is_dataclass(current) and _is_mapping(value):
        return build(type(current), value, key, base=current)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
        return list(value)
    if _is_mapping(value):  # a dict field (e.g. ``dict[str, float]``): a plain dict, its values converted
        args = typing.get_args(kind)
        item = args[1] if typing.get_origin(kind) is dict and len(args) == 2 else None
        return {str(k): _convert(value[k], item, None, f"{key}.{k}") for k in value.keys()}
    return value


def build(kind: type, mapping, prefix: str = "", base=None):
    """An instance of the dataclass ``kind``: ``base`` (default: ``kind()``) updated from ``mapping``."""
    out = copy.deepcopy(base) if base is not None else kind()
    hints = typing.get_type_hints(kind)
    names = {f.name for f in dataclasses.fields(kind) if f.init}
    for key in mapping.keys():
        name = str(key)
        full = f"{prefix}.{name}" if prefix else name
        if name not in names:
            raise ValueError(f"{full}: unknown key (known: {', '.join(sorted(names))})")
        setattr(out, name, _convert(mapping[key], hints.get(name), getattr(out, name), full))
    return out

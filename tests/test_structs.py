"""``core/structs.py`` ``build``: dataclasses from mappings, with exact known answers for the
merge, the copies, the int -> float conversion and the error naming the full key path
(surviving mutants of the second mutation run, docs/mutation.md)."""

from __future__ import annotations

import dataclasses

import pytest

from warp_terrain.core.structs import build


@dataclasses.dataclass
class Inner:
    scale: float = 1.0
    names: list = dataclasses.field(default_factory=lambda: ["a"])
    count: int = 2


@dataclasses.dataclass
class Outer:
    inner: Inner = dataclasses.field(default_factory=Inner)
    weight: float = 0.5
    tags: list = dataclasses.field(default_factory=list)


def test_unknown_keys_are_named_with_their_full_path_and_the_known_keys():
    with pytest.raises(ValueError) as top:
        build(Outer, {"wieght": 1.0})
    assert str(top.value) == "wieght: unknown key (known: inner, tags, weight)"
    with pytest.raises(ValueError) as nested:
        build(Outer, {"inner": {"scael": 2.0}})
    assert str(nested.value) == "inner.scael: unknown key (known: count, names, scale)"
    with pytest.raises(ValueError, match=r"^model\.inner\.x: unknown key"):
        build(Outer, {"inner": {"x": 1}}, prefix="model")


def test_ints_become_floats_only_for_float_fields_and_bools_stay_bools():
    out = build(Outer, {"weight": 3, "inner": {"scale": 2, "count": 5}})
    assert type(out.weight) is float and out.weight == 3.0
    assert type(out.inner.scale) is float and out.inner.scale == 2.0  # nested fields get their hints too
    assert type(out.inner.count) is int and out.inner.count == 5
    assert build(Outer, {"weight": True}).weight is True  # not silently 1.0


def test_a_nested_mapping_edits_the_base_value_not_the_default():
    base = Outer(inner=Inner(scale=7.0, names=["x", "y"], count=9), weight=0.25)
    out = build(Outer, {"inner": {"count": 3}}, base=base)
    assert out.inner == Inner(scale=7.0, names=["x", "y"], count=3) and out.weight == 0.25
    assert build(Outer, {}, base=base) == base  # nothing given: the base, not the defaults


def test_the_result_shares_nothing_with_its_base_or_its_inputs():
    base = Outer(inner=Inner(names=["x"]), tags=["t"])
    out = build(Outer, {"weight": 1.0}, base=base)
    out.inner.names.append("changed")
    out.tags.append("changed")
    assert base.inner.names == ["x"] and base.tags == ["t"]  # a deep copy of the base
    given = Inner(names=["p"])
    out = build(Outer, {"inner": given})
    out.inner.names.append("changed")
    assert given.names == ["p"]  # a dataclass value is deep-copied too
    names = ["q"]
    out = build(Outer, {"tags": names})
    out.tags.append("changed")
    assert names == ["q"]  # sequences become new lists


@dataclasses.dataclass
class Shares:
    shares: dict[str, float] = dataclasses.field(default_factory=dict)


def test_a_dict_field_from_a_dictconfig_is_a_plain_dict_of_its_value_type():
    """Hydra hands a ``dict[str, float]`` field over as a ``DictConfig``: it becomes a plain dict
    (manifests and checkpoints serialise it), ints become floats as for a float field."""
    import json

    from omegaconf import OmegaConf

    out = build(Shares, OmegaConf.create({"shares": {"pits": 1, "ditches": 0.8}}))
    assert type(out.shares) is dict and out.shares == {"pits": 1.0, "ditches": 0.8}
    assert type(out.shares["pits"]) is float
    assert json.loads(json.dumps(dataclasses.asdict(out))) == {"shares": {"pits": 1.0, "ditches": 0.8}}

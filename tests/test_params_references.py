"""File references and overrides are resolved once, at load, into values; errors name the key."""
import dataclasses as dc

import pytest
from pydrake.common.yaml import yaml_dump_typed

from alight.systems.params import ConfigError, bounded, load_params


@dc.dataclass
class Inner:
    gain: float = bounded(1.0, 0.0, 10.0)
    name: str = "a"


@dc.dataclass
class Outer:
    inner: Inner = dc.field(default_factory=Inner)
    inners: list[Inner] = dc.field(default_factory=list)
    speed: float = bounded(3.0, 0.0, 20.0, "m/s")


def test_a_file_name_or_from_mapping_is_replaced_by_the_file(tmp_path):
    (tmp_path / "inner.yaml").write_text("gain: 4.0\nname: tuned\n")
    outer = tmp_path / "outer.yaml"
    outer.write_text("inner: inner.yaml\ninners:\n  - {from: inner.yaml, gain: 5.0}\n")
    params = load_params(Outer, outer)
    assert params.inner == Inner(4.0, "tuned")
    assert params.inners == [Inner(5.0, "tuned")]
    # The dump holds values, not file names: it loads back to the same object without the file.
    (tmp_path / "inner.yaml").unlink()
    assert load_params(Outer, data=yaml_dump_typed(params)) == params


def test_overrides_apply_after_references_and_are_validated(tmp_path):
    (tmp_path / "inner.yaml").write_text("gain: 4.0\n")
    outer = tmp_path / "outer.yaml"
    outer.write_text("inner: inner.yaml\n")
    params = load_params(Outer, outer, overrides=["inner.name: b", "speed: 7"])
    assert (params.inner.gain, params.inner.name, params.speed) == (4.0, "b", 7.0)
    with pytest.raises(ConfigError, match=r"inner\.gain.*outside the allowed range"):
        load_params(Outer, outer, overrides=["inner.gain: 11"])
    with pytest.raises(ConfigError, match=r"override 'inner\.gian: 1'.*'inner\.gian'"):
        load_params(Outer, outer, overrides=["inner.gian: 1"])


def test_a_string_where_a_number_goes_names_the_file_and_key(tmp_path):
    outer = tmp_path / "outer.yaml"
    outer.write_text("speed: fast\n")
    with pytest.raises(ConfigError, match=rf"{outer}: key 'speed' = 'fast' is not a number"):
        load_params(Outer, outer)
    with pytest.raises(ConfigError, match=r"key 'inner.gain' = 'high' is not a number"):
        load_params(Outer, data="inner: {gain: high}\n")


def test_a_missing_referenced_file_names_the_key(tmp_path):
    outer = tmp_path / "outer.yaml"
    outer.write_text("inner: nowhere.yaml\n")
    with pytest.raises(ConfigError, match=r"key 'inner' = .*nowhere.yaml: parameter file not found"):
        load_params(Outer, outer)


@dc.dataclass
class Other:
    rate: float = 1.0


@dc.dataclass
class WithUnion:
    part: Inner | Other = dc.field(default_factory=Inner)


def test_an_override_keeps_the_present_union_variant(tmp_path):
    (tmp_path / "other.yaml").write_text("rate: 3.0\n")
    params = load_params(WithUnion, data="part: !Other {rate: 2.0}\n",
                         overrides=["part.rate: 5.0"])
    assert params.part == Other(5.0)
    params = load_params(WithUnion, data="part: !Other {rate: 2.0}\n",
                         overrides=[f"part: {tmp_path / 'other.yaml'}"])
    assert params.part == Other(3.0)
    assert load_params(WithUnion, data="part: {gain: 2.0}\n").part == Inner(2.0)

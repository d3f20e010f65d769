"""Typed parameters loaded from YAML, validated once at load (DESIGN.md "Parameters and errors").

Declare ranges on dataclass fields with `bounded(default, lo, hi)`; `load_params` reads a file with
`pydrake.common.yaml.yaml_load_typed` and raises `ConfigError` naming the file, the key and the
allowed range when anything is wrong.

File references are resolved once, at load: where the schema expects a parameter dataclass, the
YAML may give a file name instead (`linear_mpc: linear_mpc_landing.yaml`: that file's content), or a
mapping with `from: FILE` (that file's content, the mapping's other keys overriding it). The
loaded object holds values only, never file names, so dumping it (`yaml_dump_typed`) pins the
whole configuration. Overrides `'key.sub: value'` (Drake's hardware_sim `--scenario_text`, here
one key path per override) are applied after the references are resolved.
"""
import copy
import dataclasses as dc
import math
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed

from alight.models import MODELS_DIR

T = TypeVar("T")


class ConfigError(ValueError):
    """A parameter file or value that cannot be used; the message names file, key and range."""


def bounded(default, lo: float, hi: float, unit: str = ""):
    """A dataclass field whose value (or every element of a list value) must lie in [lo, hi];
    a list field must keep the length of its default."""
    meta = {"range": (lo, hi), "unit": unit}
    if isinstance(default, (list, tuple)):
        meta["size"] = len(default)
        return dc.field(default_factory=lambda: list(default), metadata=meta)
    return dc.field(default=default, metadata=meta)


def choice(default: str, *allowed: str):
    """A dataclass string field restricted to `allowed`."""
    return dc.field(default=default, metadata={"choices": (default,) + allowed})


def param_file(schema: type[T], filename: str):
    """A parameter-dataclass field whose default is the shipped file `filename` (models/);
    a YAML value there is a mapping, a file name or {from: FILE, ...} (`load_params`)."""
    return dc.field(default_factory=lambda: shipped_params(schema, filename))


_SHIPPED: dict[tuple, Any] = {}


def shipped_params(schema: type[T], filename: str) -> T:
    """`load_params(schema, models/filename)`, read once per process: a shipped file is never
    written while alight runs, and every dataclass with `param_file` fields builds its defaults
    from them (a scenario's load made 75 loads of 26 files). Returns a copy: the caller may
    change it."""
    path = MODELS_DIR / filename
    key = (schema, path, path.stat().st_mtime_ns if path.is_file() else None)
    if key not in _SHIPPED:
        _SHIPPED[key] = load_params(schema, path)
    return copy.deepcopy(_SHIPPED[key])


def load_params(schema: type[T], filename: str | Path | None = None, data: str | None = None,
                defaults: T | None = None, overrides: list[str] | tuple = ()) -> T:
    """Loads and validates `schema` from a YAML file or string, resolving file references and
    applying `overrides` ('key.sub: value' YAML each); raises ConfigError."""
    source = str(filename) if filename is not None else "<yaml string>"
    if filename is not None:
        tree = _read_yaml(Path(filename), source)
        base = Path(filename).parent
    else:
        tree = _parse_yaml(data or "", source)
        base = Path.cwd()
    tree = resolve_tree(schema, tree, source, base)
    for text in overrides:
        tree = apply_override(schema, tree, text)
    try:
        text = yaml.dump(tree, Dumper=_TagDumper, sort_keys=False)   # mapping order kept
        params = yaml_load_typed(schema=schema, data=text, defaults=defaults)
    except Exception as e:  # Drake raises RuntimeError / yaml errors with the key in the text.
        detail = str(e) if str(e) not in ("", "None") else "malformed or empty entry"
        raise ConfigError(f"{source}: cannot load as {schema.__name__}: {detail}") from None
    validate(params, source)
    return params


def locate(name: str | Path, base: Path | None = None) -> Path:
    """A referenced file: absolute, or beside the referencing file, or a relative path from the
    working directory, or a file name in models/."""
    path = Path(name)
    if path.is_absolute():
        return path
    for candidate in ([base / path] if base is not None else []) + [path]:
        if candidate.is_file():
            return candidate
    return MODELS_DIR / path


@dc.dataclass
class Tagged:
    """A YAML value with a `!Tag` (a variant of a Union field), kept through resolution."""
    tag: str
    value: Any


# libyaml's parser and emitter where PyYAML was built with it (its wheels are): the same
# documents, 5-10x faster than the pure-Python ones
class _TagLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    pass


class _QuotingTagLoader(yaml.SafeLoader):
    """The pure-Python parser, for its error messages: they quote the line and mark the column."""


class _TagDumper(getattr(yaml, "CSafeDumper", yaml.SafeDumper)):
    pass


def _construct_tagged(loader, suffix, node):
    if isinstance(node, yaml.MappingNode):
        value = loader.construct_mapping(node, deep=True)
    elif isinstance(node, yaml.SequenceNode):
        value = loader.construct_sequence(node, deep=True)
    else:
        value = loader.construct_scalar(node)
    return Tagged(suffix, value)


for _loader in (_TagLoader, _QuotingTagLoader):
    _loader.add_multi_constructor("!", _construct_tagged)
_TagDumper.add_representer(Tagged, lambda dumper, t: (
    dumper.represent_mapping(f"!{t.tag}", t.value or {}) if isinstance(t.value, dict) or
    t.value is None else dumper.represent_sequence(f"!{t.tag}", t.value)))


def _parse_yaml(text: str, source: str):
    try:
        tree = yaml.load(text, Loader=_TagLoader)
    except yaml.YAMLError:
        try:
            tree = yaml.load(text, Loader=_QuotingTagLoader)
        except yaml.YAMLError as e:
            raise ConfigError(f"{source}: malformed YAML: {e}") from None
    return {} if tree is None else tree


def _read_yaml(path: Path, source: str):
    if not path.is_file():
        raise ConfigError(f"{source}: parameter file not found")
    return _parse_yaml(path.read_text(), source)


FROM_KEY = "from"   # a mapping {from: FILE, key: value, ...}: FILE's content with these keys


def _schema_of(hint):
    """The dataclass a hint names (Optional allowed), or None."""
    if dc.is_dataclass(hint):
        return hint
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if _is_union(hint) and len(args) == 1 and dc.is_dataclass(args[0]):
        return args[0]
    return None


def _is_union(hint) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType)


def _variants(hint) -> dict:
    """The dataclass variants of a Union hint by tag name."""
    if not _is_union(hint):
        return {}
    return {a.__name__: a for a in typing.get_args(hint) if dc.is_dataclass(a)}


def resolve_tree(schema, tree, source: str, base: Path, prefix: str = ""):
    """`tree` (parsed YAML for `schema`) with every file reference replaced by the file's
    resolved content; checks keys and scalar types, naming `source` and the key."""
    if isinstance(tree, (str, Path)):
        path = locate(tree, base)
        where = f"{source}: key '{prefix.rstrip('.') or '<top>'}' = {path}"
        return resolve_tree(schema, _read_yaml(path, where), str(path), path.parent, prefix)
    if not isinstance(tree, dict):
        raise ConfigError(f"{source}: key '{prefix.rstrip('.') or '<top>'}' = {tree!r} must be a "
                          f"mapping of {schema.__name__} or a file name")
    if FROM_KEY in tree:
        rest = {k: v for k, v in tree.items() if k != FROM_KEY}
        tree = resolve_tree(schema, tree[FROM_KEY], source, base, prefix)
        return _merge(schema, tree, resolve_tree(schema, rest, source, base, prefix), prefix)
    hints = typing.get_type_hints(schema)
    resolved = {}
    for key, value in tree.items():
        if key not in hints:
            raise ConfigError(f"{source}: key '{prefix}{key}' is not a parameter of "
                              f"{schema.__name__} (allowed: {sorted(hints)})")
        resolved[key] = resolve_value(hints[key], value, source, base, f"{prefix}{key}")
    return resolved


def resolve_value(hint, value, source: str, base: Path, key: str):
    """One value of type `hint`: resolved (dataclasses, Union variants, lists of them) and
    type-checked (a string where a number goes names the key)."""
    nested = _schema_of(hint)
    if nested is not None and value is not None:
        return resolve_tree(nested, value, source, base, key + ".")
    variants = _variants(hint)
    if variants and isinstance(value, Tagged):
        if value.tag not in variants:
            raise ConfigError(f"{source}: key '{key}' = !{value.tag} is not one of "
                              f"{['!' + name for name in variants]}")
        return Tagged(value.tag, resolve_tree(variants[value.tag], value.value or {}, source,
                                              base, key + "."))
    if variants and value is not None:   # untagged: the first variant that fits it
        return _first_fitting(variants, value, source, base, key)
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is list and isinstance(value, list) and args:
        return [resolve_value(args[0], item, source, base, f"{key}[{i}]")
                for i, item in enumerate(value)]
    if origin is dict and isinstance(value, dict) and len(args) == 2:
        return {k: resolve_value(args[1], v, source, base, f"{key}.{k}")
                for k, v in value.items()}
    if hint is float and isinstance(value, str):
        value = _yaml_float(value)   # YAML 1.2 numbers PyYAML leaves as text (1.0e9)
    if hint in (float, int) and not (isinstance(value, (int, float)) and
                                     not isinstance(value, bool)):
        raise ConfigError(f"{source}: key '{key}' = {value!r} is not a number "
                          f"({hint.__name__} expected)")
    if hint is bool and not isinstance(value, bool):
        raise ConfigError(f"{source}: key '{key}' = {value!r} is not true or false")
    if hint is str and not isinstance(value, str):
        raise ConfigError(f"{source}: key '{key}' = {value!r} is not a string")
    return value


def _first_fitting(variants: dict, value, source: str, base: Path, key: str):
    """An untagged value of a Union: resolved as the first variant whose keys it fits, tagged
    when that is not the first (Drake reads an untagged value as the first)."""
    errors = []
    for i, (tag, schema) in enumerate(variants.items()):
        try:
            tree = resolve_tree(schema, value, source, base, key + ".")
        except ConfigError as e:
            errors.append(e)
            continue
        return tree if i == 0 else Tagged(tag, tree)
    raise errors[0]


def _yaml_float(text: str):
    """`text` as a float where YAML 1.2 (Drake's reader) reads one, else `text` itself."""
    try:
        return float(text) if text.strip().lstrip("+-")[:1].isdigit() or \
            text.strip().lstrip("+-")[:1] == "." else text
    except ValueError:
        return text


def _merge(schema, base_tree: dict, top: dict, prefix: str) -> dict:
    """`top` over `base_tree` (both resolved), recursing into nested parameter dataclasses."""
    hints = typing.get_type_hints(schema)
    merged = dict(base_tree)
    for key, value in top.items():
        nested = _schema_of(hints[key])
        if nested is not None and isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(nested, merged[key], value, f"{prefix}{key}.")
        else:
            merged[key] = value
    return merged


def apply_override(schema, tree: dict, text: str) -> dict:
    """`tree` with one override 'key.sub: value' (YAML) applied; ConfigError names the key. A
    mapping value merges into the present one; a file name replaces it with the file."""
    source = f"override {text!r}"
    item = _parse_yaml(text, source)
    if not isinstance(item, dict) or not item:
        raise ConfigError(f"{source}: expected 'key.sub: value'")
    for dotted, value in item.items():
        tree = _set_path(schema, tree, str(dotted).split("."), value, source, str(dotted))
    return tree


def _variant_of(hint, value):
    """The dataclass schema of a (resolved) value of type `hint`, or None."""
    variants = _variants(hint)
    if variants and isinstance(value, Tagged):
        return variants.get(value.tag)
    if variants:
        return next(iter(variants.values()))
    return _schema_of(hint)


def _set_path(schema, tree: dict, path: list[str], value, source: str, full: str) -> dict:
    hints = typing.get_type_hints(schema)
    key = path[0]
    if key not in hints:
        raise ConfigError(f"{source}: key '{full}': '{key}' is not a parameter of "
                          f"{schema.__name__} (allowed: {sorted(hints)})")
    tree, old = dict(tree), tree.get(key)
    nested = _variant_of(hints[key], old)
    inner = old.value if isinstance(old, Tagged) else old
    if len(path) == 1:
        # A Union value takes the present variant unless the override names its own (!Tag).
        hint = nested if _variants(hints[key]) and not isinstance(value, Tagged) else hints[key]
        new = resolve_value(hint, value, source, Path.cwd(), full)
        if nested is not None and isinstance(new, dict) and isinstance(inner, dict) and not (
                isinstance(value, (str, Path)) or FROM_KEY in value):
            new = _merge(nested, inner, new, full + ".")
    elif nested is None:
        raise ConfigError(f"{source}: key '{full}': '{key}' has no sub-keys")
    else:
        new = _set_path(nested, inner or {}, path[1:], value, source, full)
    if isinstance(old, Tagged) and not isinstance(new, Tagged):
        new = Tagged(old.tag, new)
    tree[key] = new
    return tree


def validate(params: Any, source: str = "<params>", prefix: str = "") -> None:
    """Checks every `bounded`/`choice` field (recursively) and rejects NaN/inf anywhere."""
    for f in dc.fields(params):
        key = prefix + f.name
        value = getattr(params, f.name)
        if dc.is_dataclass(value):
            validate(value, source, key + ".")
            continue
        if isinstance(value, list) and value and dc.is_dataclass(value[0]):
            for i, item in enumerate(value):
                validate(item, source, f"{key}[{i}].")
            continue
        if "choices" in f.metadata and value not in f.metadata["choices"]:
            raise ConfigError(f"{source}: key '{key}' = {value!r} is not one of "
                              f"{list(f.metadata['choices'])}")
        if "size" in f.metadata and len(value) != f.metadata["size"]:
            raise ConfigError(f"{source}: key '{key}' = {value!r} must have "
                              f"{f.metadata['size']} elements")
        numbers = _numbers(value)
        for x in numbers:
            if not math.isfinite(x):
                raise ConfigError(f"{source}: key '{key}' = {value!r} is not finite")
        if "range" in f.metadata:
            lo, hi = f.metadata["range"]
            unit = f" {f.metadata['unit']}" if f.metadata["unit"] else ""
            for x in numbers:
                if not lo <= x <= hi:
                    raise ConfigError(f"{source}: key '{key}' = {value!r} is outside the allowed "
                                      f"range [{lo}, {hi}]{unit}")


def _numbers(value) -> list[float]:
    if isinstance(value, bool):
        return []
    if isinstance(value, (int, float)):
        return [float(value)]
    if isinstance(value, (list, tuple, np.ndarray)):
        return [float(x) for x in np.ravel(value) if isinstance(x, (int, float, np.number))]
    return []

"""Typed parameters loaded from YAML, validated once at load (DESIGN.md "Parameters and errors").

Declare ranges on dataclass fields with `bounded(default, lo, hi)`; `load_params` reads a file with
`pydrake.common.yaml.yaml_load_typed` and raises `ConfigError` naming the file, the key and the
allowed range when anything is wrong.
"""
import dataclasses as dc
import math
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pydrake.common.yaml import yaml_load_typed

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


def load_params(schema: type[T], filename: str | Path | None = None, data: str | None = None,
                defaults: T | None = None) -> T:
    """Loads and validates `schema` from a YAML file or string; raises ConfigError."""
    source = str(filename) if filename is not None else "<yaml string>"
    if filename is not None and not Path(filename).is_file():
        raise ConfigError(f"{source}: parameter file not found")
    try:
        params = yaml_load_typed(schema=schema, filename=str(filename) if filename else None,
                                 data=data, defaults=defaults)
    except Exception as e:  # Drake raises RuntimeError / yaml errors with the key in the text.
        detail = str(e) if str(e) not in ("", "None") else "malformed or empty entry"
        raise ConfigError(f"{source}: cannot load as {schema.__name__}: {detail}") from None
    validate(params, source)
    return params


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

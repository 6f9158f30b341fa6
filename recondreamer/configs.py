"""Configs as plain data: dataclass configs <-> dicts, and the workflow's layered config files.

Dataclass configs: the one conversion every checkpoint, run record and manifest uses.

A config round-trips, ``from_dict(type(config), to_dict(config)) == config``. ``to_dict`` gives
JSON-ready nested dicts (tuples become lists); ``from_dict`` rebuilds nested dataclasses from the
fields' type hints and turns lists back into tuples where a field is a tuple. A stored config
must name exactly its class's fields: one written by another version of the code is refused with
the names that differ, never silently completed with today's defaults (a default may have changed
since). ``partial=True`` lets left-out fields take their defaults, for overrides.

Workflow configs: ``config/config.yaml`` holds every key; any other config file sets only what
differs and is layered over it (``layer``, ``workflow_config``), by the Snakefile and by every
script or test that reads a config the way a run does.
"""

from __future__ import annotations

import dataclasses
import functools
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from recondreamer.errors import RecondreamerError

T = TypeVar("T")

DEFAULT_WORKFLOW_CONFIG = Path("config") / "config.yaml"  # relative to the repository root
# Mappings of named entries (segments, local checkpoints): an override's mapping replaces the
# default's whole, so that a config's segment list never gains the default's segments.
WHOLE_MAPPINGS = ("synthetic.segments", "waymo.segments", "restorer.checkpoints")


def to_dict(config: Any) -> dict:
    """A dataclass instance as nested dicts and lists (JSON-ready)."""
    if not dataclasses.is_dataclass(config) or isinstance(config, type):
        raise TypeError(f"to_dict expects a dataclass instance, got {type(config).__name__}")
    return _plain(dataclasses.asdict(config))


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value


def from_dict(cls: type[T], values: Mapping, *, partial: bool = False) -> T:
    """Rebuild ``cls`` from ``values`` (what ``to_dict`` wrote); RecondreamerError naming the fields
    that are unknown or, unless ``partial``, missing."""
    if not isinstance(values, Mapping):
        raise RecondreamerError(f"{cls.__name__}: expected a mapping of fields, got {type(values).__name__}")
    names = [field.name for field in dataclasses.fields(cls) if field.init]
    unknown = sorted(set(values) - set(names))
    missing = [] if partial else [name for name in names if name not in values]
    if unknown or missing:
        problems = ([f"unknown field(s) {unknown}"] if unknown else []) + ([f"missing field(s) {missing}"] if missing else [])
        raise RecondreamerError(f"{cls.__name__}: {'; '.join(problems)} (a config written by another version of the code?)")
    hints = _type_hints(cls)
    return cls(**{name: _coerce(hints[name], value, partial) for name, value in values.items()})


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _coerce(hint: Any, value: Any, partial: bool) -> Any:
    """``value`` as a field of type ``hint`` holds it: dataclasses rebuilt, lists made tuples."""
    if value is None:
        return None
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        options = [arg for arg in typing.get_args(hint) if arg is not type(None)]
        return _coerce(options[0], value, partial) if len(options) == 1 else value
    if dataclasses.is_dataclass(hint) and isinstance(value, Mapping):
        return from_dict(hint, value, partial=partial)
    if origin is tuple and isinstance(value, (list, tuple)):
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], item, partial) for item in value)
        if args and len(args) == len(value):
            return tuple(_coerce(arg, item, partial) for arg, item in zip(args, value))
        return tuple(value)
    return value


def layer(base: Mapping, override: Mapping, whole: tuple[str, ...] = WHOLE_MAPPINGS, _prefix: str = "") -> dict:
    """``override`` over ``base``: mappings merge key by key, except the dotted keys in ``whole``;
    every other value (lists included) replaces the base's."""
    merged = dict(base)
    for key, value in override.items():
        dotted = _prefix + str(key)
        if isinstance(value, Mapping) and isinstance(base.get(key), Mapping) and dotted not in whole:
            merged[key] = layer(base[key], value, whole, dotted + ".")
        else:
            merged[key] = value
    return merged


def read_yaml_mapping(path: str | Path) -> dict:
    """A YAML file holding a mapping (an empty file is an empty one); RecondreamerError naming the file otherwise."""
    try:
        content = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as error:
        raise RecondreamerError(f"{path}: not a readable YAML config ({error})") from error
    if content is None:
        return {}
    if not isinstance(content, Mapping):
        raise RecondreamerError(f"{path}: a config file must hold a mapping of keys, got {type(content).__name__}")
    return dict(content)


def workflow_config(*overrides: str | Path, root: str | Path = ".") -> dict:
    """The config a run with ``--configfile OVERRIDES...`` uses: the default config with each file
    layered over it in order (paths relative to ``root``, the repository root)."""
    config = read_yaml_mapping(Path(root) / DEFAULT_WORKFLOW_CONFIG)
    for path in overrides:
        config = layer(config, read_yaml_mapping(Path(root) / path))
    return config


def check_workflow_config(config: Mapping, schema_file: str | Path, sources: list[str | Path]) -> None:
    """Validate a layered workflow config against its JSON schema; RecondreamerError naming the
    config file that set the offending key (the last of ``sources``, the layered files in order,
    that holds it), the key and what is wrong. A key no file sets came from ``--config``."""
    import jsonschema

    schema = yaml.safe_load(Path(schema_file).read_text())
    errors = list(jsonschema.validators.validator_for(schema)(schema).iter_errors(config))
    if not errors:
        return
    error = jsonschema.exceptions.best_match(errors)
    path = [str(part) for part in error.absolute_path]
    key = ".".join(path) or "(top level)"
    value = _lookup(config, path)
    where = "--config (no config file sets it to this value)"
    for source in reversed(sources):
        found = _lookup(read_yaml_mapping(source), path)
        if found is not _UNSET:
            where = str(source) if found == value else where  # a different value: --config replaced the file's
            break
    more = f" ({len(errors) - 1} more problem(s) after fixing it)" if len(errors) > 1 else ""
    raise RecondreamerError(f"{where}: config key {key}: {error.message}{more}")


_UNSET = object()


def _lookup(mapping: Any, path: list[str]) -> Any:
    """The value at the key path ``path`` of nested mappings, or ``_UNSET``."""
    for part in path:
        mapping = mapping.get(part, _UNSET) if isinstance(mapping, Mapping) else _UNSET
    return mapping

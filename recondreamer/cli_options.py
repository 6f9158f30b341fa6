"""Command-line options generated from dataclass configs: one flag per field, help from the field's comment.

A command names the fields it exposes; each becomes ``--field-name`` (with an optional prefix),
typed from the field's annotation (``bool`` fields take ``on``/``off``, tuples take several
values), its help the comment written beside or above the field in the config class, followed
by the default the command uses (or "required" for the fields a command cannot default). Options
default to ``None``: ``apply_options`` replaces only the fields given on the command line, then runs
the config's own ``check()`` (if it has one), whose ``ConfigValueError`` comes back naming the flag;
``naming_flags`` does the same for a config a command builds itself. So a field, its meaning, its
default and its valid range each have one home: the config class.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import dataclasses
import functools
import inspect
import io
import textwrap
import tokenize
import types
import typing
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from recondreamer.errors import ConfigValueError, RecondreamerError

def flag(name: str, prefix: str = "") -> str:
    return "--" + prefix + name.replace("_", "-")


@functools.cache
def field_comments(cls: type) -> dict[str, str]:
    """Field name -> the comment beside its definition in ``cls``'s source, else the comment lines right above it."""
    source = textwrap.dedent(inspect.getsource(cls))
    lines = source.splitlines()
    trailing: dict[int, str] = {}
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            trailing[token.start[0]] = token.string.lstrip("#").strip()
    comments = {}
    for node in ast.parse(source).body[0].body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        line = node.lineno
        if line in trailing and lines[line - 1].lstrip()[:1] != "#":
            comments[node.target.id] = trailing[line]
            continue
        above = []
        while line - 1 - len(above) >= 1 and lines[line - 2 - len(above)].lstrip().startswith("#"):
            above.insert(0, lines[line - 2 - len(above)].lstrip().lstrip("#").strip())
        comments[node.target.id] = " ".join(above)
    return comments


def _field_type(cls: type, name: str) -> Any:
    return typing.get_type_hints(cls)[name]


def _on_off(value: str) -> bool:
    if value not in ("on", "off"):
        raise argparse.ArgumentTypeError(f"expected on or off, got {value!r}")
    return value == "on"


def _show(value: Any) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, tuple):
        return " ".join(_show(item) for item in value)
    return str(value)


def add_config_options(
    parser: argparse.ArgumentParser,
    cls: type,
    names: Sequence[str],
    defaults: Any = None,  # an instance of cls whose values the help shows (default: cls()), or {field: text, "*": text}
    prefix: str = "",
    title: str | None = None,
    required: Sequence[str] = (),  # fields of names the command line must give (help says "required", no default)
) -> None:
    """One ``--[prefix]field-name`` option per field in ``names`` of the dataclass ``cls``."""
    fields = {field.name: field for field in dataclasses.fields(cls)}
    unknown = [name for name in names if name not in fields]
    if unknown:
        raise ValueError(f"{cls.__name__} has no field(s) {unknown}")
    if not set(required) <= set(names):
        raise ValueError(f"required field(s) {sorted(set(required) - set(names))} are not among {list(names)}")
    shown = cls() if defaults is None else defaults
    comments = field_comments(cls)
    group = parser.add_argument_group(title or f"{cls.__name__} options")
    for name in names:
        hint = _field_type(cls, name)
        if typing.get_origin(hint) in (typing.Union, types.UnionType):  # X | None: the option takes an X
            hint = next(arg for arg in typing.get_args(hint) if arg is not type(None))
        origin = typing.get_origin(hint)
        if name in required:
            shown_default = "required"
        elif isinstance(shown, Mapping):
            shown_default = f"default: {shown.get(name) or shown['*']}"
        else:
            shown_default = f"default: {_show(getattr(shown, name))}"
        help_text = f"{comments.get(name) or name.replace('_', ' ')} ({shown_default})"
        kwargs: dict[str, Any] = {"default": None, "help": help_text.replace("%", "%%"), "dest": prefix.replace("-", "_") + name,
                                  "required": name in required}
        if hint is bool:
            kwargs.update(type=_on_off, metavar="{on,off}")
        elif origin is tuple:
            args = typing.get_args(hint)
            item = args[0]
            kwargs.update(type=item, nargs="+" if len(args) == 2 and args[1] is Ellipsis else len(args), metavar=name.upper())
        else:
            kwargs.update(type=hint, metavar=name.upper())
        group.add_argument(flag(name, prefix), **kwargs)


def apply_options(args: argparse.Namespace, config: Any, names: Sequence[str], prefix: str = "") -> Any:
    """``config`` with every option of ``names`` that was given replaced, then checked by ``config.check()``."""
    given = {}
    for name in names:
        value = getattr(args, prefix.replace("-", "_") + name)
        if value is not None:
            given[name] = tuple(value) if isinstance(value, list) else value
    config = dataclasses.replace(config, **given)
    check_config(config, prefix)
    return config


@contextlib.contextmanager
def naming_flags(prefix: str = "") -> Iterator[None]:
    """A ConfigValueError raised inside comes back as a RecondreamerError naming the command-line flag."""
    try:
        yield
    except ConfigValueError as error:
        raise RecondreamerError(f"{flag(error.field, prefix)} {error.message}") from None


def check_config(config: Any, prefix: str = "") -> None:
    """Run ``config.check()``; a ConfigValueError comes back naming the command-line flag."""
    check = getattr(config, "check", None)
    if check is None:
        return
    with naming_flags(prefix):
        check()

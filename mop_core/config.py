"""Typed configuration: build frozen dataclasses from plain mappings with errors that name the key.

mop_core never reads ``params.yaml``; a stage script loads it and hands the relevant section to
:func:`from_mapping`, which rejects unknown keys, missing keys and values of the wrong type, and
re-raises every ``ConfigError`` from a dataclass's own ``__post_init__`` checks prefixed with the
full dotted key (``collect.schedule.medium_step: ...``), before any compute starts.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import types
import typing
from typing import Any, Iterator, Mapping, TypeVar

T = TypeVar("T")


class ConfigError(ValueError):
    """A parameter has a wrong value; the message starts with the parameter's dotted key."""


class InputFileError(ValueError):
    """An input file is missing, unreadable, or not what the run expects; the message starts with its path.

    Stage scripts report it like a ConfigError: one line, exit status 2."""


class OutputFileError(RuntimeError):
    """An output could not be written (e.g. the disk is full); the message starts with its path and says
    that the previous file, if any, is untouched."""


def first_line(err: BaseException) -> str:
    """An exception as one line: its type and the first line of its message."""
    lines = str(err).strip().splitlines()
    return f"{type(err).__name__}: {lines[0]}" if lines else type(err).__name__


def require(condition: bool, key: str, expected: str, value: Any) -> None:
    """Raise ``ConfigError('<key>: expected <expected>, got <value>')`` unless ``condition``."""
    if not condition:
        raise ConfigError(f"{key}: expected {expected}, got {value!r}")


def require_unique(values, key: str) -> None:
    """Grid lists (seeds, levels, actors, losses) name distinct runs: a repeat would count one run twice."""
    seen = set()
    for value in values:
        if value in seen:
            raise ConfigError(f"{key}: expected a list without repeats, got {list(values)!r} ({value!r} twice)")
        seen.add(value)


def _coerce(value: Any, annotation: Any, key: str) -> Any:  # noqa: C901 (one branch per annotation kind)
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        non_none = [a for a in args if a is not type(None)]
        if len(non_none) == 1:
            return _coerce(value, non_none[0], key)
        errors = []
        for option in non_none:  # the first reading that fits (e.g. a number, else a mapping of numbers)
            try:
                return _coerce(value, option, key)
            except ConfigError as err:
                errors.append(str(err).removeprefix(f"{key}: ").removeprefix("expected ").split(", got ")[0])
        raise ConfigError(f"{key}: expected {' or '.join(errors)}{' or null' if type(None) in args else ''}, "
                          f"got {value!r}")
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{key}: expected a mapping of {annotation.__name__} fields, got {value!r}")
        return from_mapping(annotation, value, key)
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{key}: expected a mapping, got {value!r}")
        if len(args) == 2 and args[1] is not Any:
            return {k: _coerce(v, args[1], f"{key}.{k}") for k, v in value.items()}
        return dict(value)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        item_type = args[0] if args else Any
        return tuple(_coerce(v, item_type, f"{key}[{i}]") for i, v in enumerate(value))
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, str):  # YAML reads 3e-4 (no dot) as a string
            try:
                value = float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        if not math.isfinite(value):  # no parameter of the study gives inf or nan a meaning
            raise ConfigError(f"{key}: expected a finite number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    return value


def from_mapping(cls: type[T], mapping: Mapping[str, Any], where: str) -> T:
    """Build dataclass ``cls`` from ``mapping``; every error names ``where.<field>``."""
    if not isinstance(mapping, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {mapping!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(mapping) - set(fields))
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}: unknown parameter; known: {', '.join(sorted(fields))}")
    kwargs = {}
    for name, field in fields.items():
        key = f"{where}.{name}"
        if name not in mapping:
            if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{key}: missing required parameter")
            continue
        kwargs[name] = _coerce(mapping[name], hints[name], key)
    try:
        return cls(**kwargs)
    except ConfigError as err:
        message = str(err)
        if message.startswith(f"{where}."):
            raise
        raise ConfigError(f"{where}.{message}") from None


@contextlib.contextmanager
def keys_under(section: str) -> Iterator[None]:
    """Report a library ConfigError (keys relative to a config, ``pbrl.batch_size``) under the params
    section the config came from (``train_teachers.pbrl.batch_size``)."""
    try:
        yield
    except ConfigError as err:
        message = str(err)
        if message.startswith(f"{section}."):
            raise
        raise ConfigError(f"{section}.{message}") from None


def to_dict(config: Any) -> dict[str, Any]:
    """A dataclass as nested plain dicts/lists (JSON- and YAML-serialisable)."""

    def plain(value: Any) -> Any:
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        return value

    return plain(dataclasses.asdict(config))

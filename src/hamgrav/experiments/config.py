"""Experiment configurations: frozen dataclasses read from TOML and from command-line options,
checked at the edge, and written back into results.json."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from pathlib import Path

from ..errors import InputError
from ..io.files import read_toml

__all__ = ["ExperimentConfig", "option"]


def option(default, help: str):  # noqa: A002 (the CLI's word)
    """A config field with its help text (shown by ``hamgrav experiment NAME --help``)."""
    if isinstance(default, list | dict | set):
        raise TypeError("config defaults must be immutable")
    return dataclasses.field(default=default, metadata={"help": help})


def _coerce(name: str, kind, value):
    """``value`` as the field type ``kind`` (int, float, str, bool, tuple[T, ...], T | None);
    strings from the command line are parsed (tuples as comma-separated lists)."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(kind) if a is not type(None)]
        if value is None or (isinstance(value, str) and value.lower() == "none"):
            return None
        return _coerce(name, options[0], value)
    if origin is tuple:
        item = typing.get_args(kind)[0]
        if isinstance(value, str):
            value = [v for v in value.split(",") if v.strip()]
        if not isinstance(value, list | tuple):
            raise InputError(f"{name} must be a list, got {value!r}")
        return tuple(_coerce(name, item, v) for v in value)
    if kind is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false"):
            return value.lower() == "true"
        raise InputError(f"{name} must be true or false, got {value!r}")
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int | str):
            raise InputError(f"{name} must be an integer, got {value!r}")
        try:
            return int(value)
        except ValueError:
            raise InputError(f"{name} must be an integer, got {value!r}") from None
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, int | float | str):
            raise InputError(f"{name} must be a number, got {value!r}")
        try:
            number = float(value)
        except ValueError:
            raise InputError(f"{name} must be a number, got {value!r}") from None
        if not math.isfinite(number):  # NaN passes every range check of ``check``
            raise InputError(f"{name} must be a finite number, got {value!r}")
        return number
    if kind is str:
        if not isinstance(value, str):
            raise InputError(f"{name} must be a string, got {value!r}")
        return value
    raise TypeError(f"unsupported config field type {kind!r}")


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """Base of experiment configurations. Subclasses are frozen dataclasses whose fields are
    declared with :func:`option` (a default and a help text); ``check`` validates values."""

    @classmethod
    def field_types(cls) -> dict[str, object]:
        """Field name -> resolved type."""
        hints = typing.get_type_hints(cls)
        return {f.name: hints[f.name] for f in dataclasses.fields(cls)}

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> ExperimentConfig:
        """A config from plain data; unknown keys and bad values raise :class:`InputError`
        naming ``source``, the key and what is allowed."""
        types_ = cls.field_types()
        unknown = sorted(set(data) - set(types_))
        if unknown:
            raise InputError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(types_)}")
        try:
            values = {k: _coerce(k, types_[k], v) for k, v in data.items()}
            config = cls(**values)
            config.check()
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
        return config

    @classmethod
    def from_toml(cls, path: str | Path) -> ExperimentConfig:
        """A config from a TOML file of top-level keys."""
        try:
            data = read_toml(path)
        except InputError as exc:
            raise InputError(f"config {exc}") from None
        return cls.from_dict(data, source=str(path))

    def updated(self, overrides: dict, source: str = "options") -> ExperimentConfig:
        """This config with ``overrides`` (None values ignored) applied and checked."""
        given = {k: v for k, v in overrides.items() if v is not None}
        return type(self).from_dict({**self.as_dict(), **given}, source)

    def as_dict(self) -> dict:
        """Plain data (tuples as lists) that :meth:`from_dict` reads back."""
        return {
            k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()
        }

    def check(self) -> None:
        """Raise :class:`InputError` for invalid values (subclasses extend this)."""

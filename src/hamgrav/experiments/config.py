"""Experiment configurations: frozen dataclasses read from TOML and from command-line options,
checked at the edge, and written back into results.json."""

from __future__ import annotations

import contextvars
import dataclasses
import math
import types
import typing
from pathlib import Path

from ..errors import InputError
from ..files import read_toml

__all__ = ["ExperimentConfig", "option", "label", "largest_parameters", "COMMAND_LINE"]

#: Options holding SH degrees (one or several) in the experiments' configs: the largest sets
#: the parameter count of the largest SH fit (see :func:`largest_parameters`).
SH_DEGREE_OPTIONS = (
    "sh_degrees",
    "sh_degree",
    "kaula_degrees",
    "descent_degrees",
    "map_degrees",
    "gravity_only_degree",
    "max_degree",
)

#: The ``source`` of a config built from command-line options: its errors name the options
#: (``--shells-rb``) rather than the keys of a config file (``shells_rb``).
COMMAND_LINE = "command-line options"

#: Where the config being read comes from (see :func:`label`).
_SOURCE: contextvars.ContextVar[str] = contextvars.ContextVar("config_source", default="config")


def option(
    default,
    help: str,  # noqa: A002 (the CLI's word)
    *,
    at_least: float | None = None,
    above: float | None = None,
    at_most: float | None = None,
    nonempty: bool = False,
):
    """A config field with its help text (shown by ``hamgrav experiment NAME --help``) and
    optional bounds on its value, or on every item of a list: ``at_least`` and ``at_most``
    inclusive, ``above`` exclusive, in the field's own unit; ``nonempty``: a list needs at
    least one item. The bounds are checked when a config is read, before anything runs."""
    if isinstance(default, list | dict | set):
        raise TypeError("config defaults must be immutable")
    bounds = {"at_least": at_least, "above": above, "at_most": at_most}
    bounds = {k: v for k, v in bounds.items() if v is not None}
    if nonempty:
        bounds["nonempty"] = True
    return dataclasses.field(default=default, metadata={"help": help, "bounds": bounds})


def _label(name: str, source: str) -> str:
    """How an error names field ``name``: its option on the command line, else its key."""
    return f"--{name.replace('_', '-')}" if source == COMMAND_LINE else name


def label(name: str) -> str:
    """How an error raised while a config is read (in ``check``) names field ``name``: its
    command-line option (``--shells-rb``) when the config comes from the command line, else
    its key (``shells_rb``)."""
    return _label(name, _SOURCE.get())


def _check_bounds(shown_as: str, value, bounds: dict) -> None:
    """Raise :class:`InputError` when ``value`` (a number or a tuple of them; None passes)
    breaks one of ``bounds`` (see :func:`option`)."""
    if value is None or not bounds:
        return
    if bounds.get("nonempty") and isinstance(value, tuple) and not value:
        raise InputError(f"{shown_as} needs at least one value")
    items = value if isinstance(value, tuple) else (value,)
    what = f"every value of {shown_as}" if isinstance(value, tuple) else shown_as
    shown = ",".join(map(str, value)) if isinstance(value, tuple) else value
    for item in items:
        if "at_least" in bounds and not item >= bounds["at_least"]:
            raise InputError(f"{what} must be at least {bounds['at_least']}, got {shown}")
        if "above" in bounds and not item > bounds["above"]:
            raise InputError(f"{what} must be above {bounds['above']}, got {shown}")
        if "at_most" in bounds and not item <= bounds["at_most"]:
            raise InputError(f"{what} must be at most {bounds['at_most']}, got {shown}")


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
        token = _SOURCE.set(source)
        try:
            values = {k: _coerce(_label(k, source), types_[k], v) for k, v in data.items()}
            config = cls(**values)
            for f in dataclasses.fields(cls):
                bounds = f.metadata.get("bounds", {})
                _check_bounds(_label(f.name, source), getattr(config, f.name), bounds)
            config.check()
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
        finally:
            _SOURCE.reset(token)
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

    #: what to lower when one repetition does not fit in memory (the sizing error's fix)
    memory_fix: typing.ClassVar[str] = "lower the experiment's sizes"

    def memory_parts(self) -> dict[str, float]:
        """The largest arrays one repetition holds at its peak [bytes] (:mod:`hamgrav.sizing`),
        from the options alone, so that a job that cannot fit is refused before it starts;
        empty: nothing to size (subclasses with campaigns and fits fill it in)."""
        return {}

    def check(self) -> None:
        """Raise :class:`InputError` for invalid values (subclasses extend this)."""


def largest_parameters(config: ExperimentConfig) -> int:
    """Parameters of the largest fit ``config`` asks for: one network of its ``hidden`` layers
    (members are fitted one at a time) or the SH expansion of its highest degree among
    :data:`SH_DEGREE_OPTIONS`, (L + 1)^2 - 4 coefficients; 0 when it has neither."""
    from ..core.terms import SphericalHarmonics
    from ..sizing import network_parameters

    counts = [0]
    if getattr(config, "hidden", None):
        counts.append(network_parameters(config.hidden))
    for name in SH_DEGREE_OPTIONS:
        degrees = getattr(config, name, None)
        if degrees is None:
            continue
        for degree in degrees if isinstance(degrees, tuple) else (degrees,):
            counts.append(SphericalHarmonics(int(degree), 1.0).n_params)
    return max(counts)

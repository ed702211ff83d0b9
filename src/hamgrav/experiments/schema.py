"""results.json checked before it is rendered: a hand-edited file gets one line naming the JSON
path of its first problem, not a KeyError or TypeError from deep inside a README table.

Two layers, because each experiment's README reads its own keys:

- :data:`REPORT`: the keys every results.json has and the runner's README header reads
  (experiment, command, seeds, dispatch, wall_s, repetitions, config, aggregate, figures),
  checked by :func:`validate` against a small hand-rolled schema: a Python type (or tuple of
  types), :data:`NUMBER`, a dict of required keys (:class:`Optional` for the others),
  ``[item]`` for a list (:class:`NonEmpty` for one of at least one item), :class:`Each` for
  a dict of any keys with values of one schema.
- the experiment's own part: the README is rendered from a :func:`traced` copy of the report
  that records the JSON path of every value read, so that a missing key or a value of the
  wrong type found while rendering (KeyError, TypeError, ...) names the path it was read at
  (:func:`render_checked`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ..errors import InputError

__all__ = [
    "NUMBER",
    "REPORT",
    "Each",
    "NonEmpty",
    "Optional",
    "render_checked",
    "traced",
    "validate",
]

#: A JSON number (int or float, not a bool).
NUMBER = (int, float)


@dataclass(frozen=True)
class Optional:
    """A key that may be missing (its value, when present, follows ``schema``)."""

    schema: object


@dataclass(frozen=True)
class NonEmpty:
    """A list of at least one item, each following ``schema``."""

    schema: object


@dataclass(frozen=True)
class Each:
    """A dict of any keys whose values all follow ``schema``."""

    schema: object


#: What every results.json holds (see :mod:`hamgrav.experiments.runner`).
REPORT = {
    "experiment": str,
    "command": str,
    "config": Each(object),
    "seeds": NonEmpty(int),
    "dispatch": str,
    "wall_s": NUMBER,
    "repetitions": NonEmpty(dict),
    "aggregate": dict,
    "figures": Optional([str]),
    "merged_from": Optional(NonEmpty({"folder": str, "command": str, "seeds": NonEmpty(int)})),
}

_NAMES = {str: "a string", int: "an integer", float: "a number", dict: "an object", list: "a list"}


def _kind(schema) -> str:
    if schema is NUMBER:
        return "a number"
    if isinstance(schema, tuple):
        return " or ".join(_kind(s) for s in schema)
    if isinstance(schema, dict | Each):
        return "an object"
    if isinstance(schema, list | NonEmpty):
        return "a list"
    return _NAMES.get(schema, getattr(schema, "__name__", str(schema)))


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def problem(value, schema, path: str = "$") -> str | None:
    """The first place where ``value`` breaks ``schema``, as ``"<path> <what is wrong>"``, or
    None when it follows it."""
    if schema is object:
        return None
    if isinstance(schema, dict):
        if not isinstance(value, dict):
            return f"{path} must be an object, got {_shown(value)}"
        for key, sub in schema.items():
            if key not in value:
                if isinstance(sub, Optional):
                    continue
                return f"{path}.{key} is missing"
            sub = sub.schema if isinstance(sub, Optional) else sub
            found = problem(value[key], sub, f"{path}.{key}")
            if found:
                return found
        return None
    if isinstance(schema, Each):
        if not isinstance(value, dict):
            return f"{path} must be an object, got {_shown(value)}"
        for key, item in value.items():
            found = problem(item, schema.schema, f"{path}.{key}")
            if found:
                return found
        return None
    if isinstance(schema, list | NonEmpty):
        if not isinstance(value, list):
            return f"{path} must be a list, got {_shown(value)}"
        if isinstance(schema, NonEmpty) and not value:
            return f"{path} must not be empty"
        item_schema = schema.schema if isinstance(schema, NonEmpty) else schema[0]
        for k, item in enumerate(value):
            found = problem(item, item_schema, f"{path}[{k}]")
            if found:
                return found
        return None
    types = schema if isinstance(schema, tuple) else (schema,)
    if isinstance(value, bool) and bool not in types:
        return f"{path} must be {_kind(schema)}, got {_shown(value)}"
    if not isinstance(value, types):
        return f"{path} must be {_kind(schema)}, got {_shown(value)}"
    return None


def validate(value, schema, source: str, fix: str) -> None:
    """Raise :class:`InputError` "``source``: <path> <problem>; ``fix``" when ``value``
    breaks ``schema``."""
    found = problem(value, schema)
    if found:
        raise InputError(f"{source}: {found}; {fix}")


# ------------------------------------------------------------------------- traced reading
class _Trace:
    """The JSON path of the value read last."""

    def __init__(self) -> None:
        self.path = "$"


class _TracedDict(dict):
    def __init__(self, data: dict, path: str, trace: _Trace):
        super().__init__({k: _wrap(v, f"{path}.{k}", trace) for k, v in data.items()})
        self._path, self._trace = path, trace

    def __getitem__(self, key):
        self._trace.path = f"{self._path}.{key}"
        return super().__getitem__(key)

    def get(self, key, default=None):
        self._trace.path = f"{self._path}.{key}"
        return super().get(key, default)

    def items(self):
        for key, value in super().items():
            self._trace.path = f"{self._path}.{key}"
            yield key, value

    def values(self):
        for _, value in self.items():
            yield value


class _TracedList(list):
    def __init__(self, data: list, path: str, trace: _Trace):
        super().__init__(_wrap(v, f"{path}[{k}]", trace) for k, v in enumerate(data))
        self._path, self._trace = path, trace

    def __getitem__(self, index):
        if isinstance(index, int):
            self._trace.path = f"{self._path}[{index if index >= 0 else len(self) + index}]"
        return super().__getitem__(index)

    def __iter__(self):
        for k, value in enumerate(super().__iter__()):
            self._trace.path = f"{self._path}[{k}]"
            yield value


def _wrap(value, path: str, trace: _Trace):
    if isinstance(value, dict):
        return _TracedDict(value, path, trace)
    if isinstance(value, list):
        return _TracedList(value, path, trace)
    return value


def traced(report: dict) -> tuple[dict, _Trace]:
    """A copy of ``report`` that records in the returned trace the path of each value read."""
    trace = _Trace()
    return _TracedDict(report, "$", trace), trace


def render_checked(render: Callable[[dict], object], report: dict, source: str, fix: str):
    """``render(report)`` on a :func:`traced` copy; a KeyError, TypeError, ValueError,
    IndexError or AttributeError raised by it (a key missing, a value of another type than
    the renderer reads) becomes :class:`InputError` naming ``source``, the JSON path read
    last and the ``fix``."""
    copy, trace = traced(report)
    try:
        return render(copy)
    except KeyError:
        raise InputError(f"{source}: {trace.path} is missing; {fix}") from None
    except (TypeError, ValueError, IndexError, AttributeError, ZeroDivisionError) as exc:
        raise InputError(
            f"{source}: {trace.path} holds a value of another kind than expected ({exc}); {fix}"
        ) from None

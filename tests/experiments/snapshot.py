"""Every number a tiny experiment records, compared with the same run's numbers at the commit
that wrote its snapshot (``tests/experiments/snapshots/<name>.json``): a refactoring of the
campaign pipeline must leave them unchanged to rounding.

Timings, memory, the command line and the version are left out (they change from run to run).
After a change that is meant to move the numbers, write the snapshots again with
``HAMGRAV_UPDATE_SNAPSHOTS=1 make test`` (or that variable on the tests concerned) and say in
the commit why they moved.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

FOLDER = Path(__file__).with_name("snapshots")
#: Relative tolerance: rounding, not behaviour (the runs are deterministic on one machine;
#: another CPU may round differently in the last digits).
RTOL = 1e-6
#: Leaves that are not results: they differ between two runs of the same command (so do
#: timings, every key that starts with "wall").
VOLATILE = {"command", "hamgrav_version", "dispatch", "peak_memory_mb", "figures"}
#: A number written in a message (e.g. "relative cost change 7.35e-15 < 1e-06").
NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def _leaves(value, path=()):
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, (*path, str(key)))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _leaves(item, (*path, str(index)))
    elif not (set(path) & VOLATILE or any(p.startswith("wall") for p in path)):
        yield "/".join(path), value


def _same_text(expected: str, got: str) -> bool:
    """Messages match when their words do and their numbers agree as numbers do (a solver's
    "relative cost change" at rounding level differs between two runs in its digits)."""
    if NUMBER.split(expected) != NUMBER.split(got):
        return False
    pairs = zip(NUMBER.findall(expected), NUMBER.findall(got), strict=True)
    return all(_same(float(a), float(b)) for a, b in pairs)


def _same(expected, got) -> bool:
    if isinstance(expected, str) and isinstance(got, str):
        return _same_text(expected, got)
    if isinstance(expected, float) or isinstance(got, float):
        if expected is None or got is None or isinstance(expected, bool | str):
            return expected == got
        if math.isnan(expected) and math.isnan(got):
            return True
        return math.isclose(expected, got, rel_tol=RTOL, abs_tol=1e-12)
    return expected == got


def check_snapshot(name: str, results_json: Path) -> None:
    """Assert that the results at ``results_json`` hold the numbers of snapshot ``name``
    (written instead when ``HAMGRAV_UPDATE_SNAPSHOTS`` is set)."""
    got = dict(_leaves(json.loads(Path(results_json).read_text())))
    path = FOLDER / f"{name}.json"
    if os.environ.get("HAMGRAV_UPDATE_SNAPSHOTS"):
        FOLDER.mkdir(exist_ok=True)
        path.write_text(json.dumps(got, indent=0, sort_keys=True) + "\n")
        return
    assert path.exists(), f"no snapshot {path}: write it with HAMGRAV_UPDATE_SNAPSHOTS=1"
    expected = json.loads(path.read_text())
    missing = sorted(set(expected) - set(got))
    added = sorted(set(got) - set(expected))
    assert not missing and not added, f"{name}: leaves gone {missing[:5]}, new {added[:5]}"
    moved = {k: (expected[k], got[k]) for k in expected if not _same(expected[k], got[k])}
    assert not moved, f"{name}: {len(moved)} number(s) moved, e.g. {dict(list(moved.items())[:5])}"

"""Size a job before it starts: the memory its largest arrays need, against the memory there is.

Every bound of a single option (at most 1000 orbits, 10 000 arcs per orbit, 10 000 samples
per arc, 1024 units per hidden layer...) can hold while their product cannot: 1000 x 10 000
x 10 000 samples is 10 TiB of states, three hidden layers of 1024 units a 32 TiB normal
matrix. The commands add up the arrays a job holds at its peak (float64, 8 bytes a number),
from its sizes alone, and refuse it in one line, with the figure and the fix, when they
exceed the limit: ``--max-memory`` (e.g. ``8GiB``) or, by default, the memory the machine
has available now (psutil's ``available``: free memory plus what the kernel can reclaim).

The figures are estimates of the largest arrays, not a measurement: Python objects, the
compiled integrators' code and small arrays are left out. They are meant to tell a job that
cannot fit (a factor of 2 or 1000 over) from one that can, before it runs for minutes and
dies with MemoryError. What is counted, per kind of job:

- arcs: times (1) and noisy and true states (6 + 6): 13 numbers a sample;
- a simulated campaign: the arcs, their per-orbit pieces before they are joined (7 a
  sample) and the noise drawn for them (6), and one orbit's propagation grid (its samples
  and the graze-check grid, 6 numbers a point, twice: the grid and its states);
- a design block (a batch of ``chunk`` arcs): the sensitivities d state / d parameters of
  the batch, m x 6 x P numbers an arc, twice (the integrator's output and the columns
  scattered into the global parameter vector);
- the integrator of the variational equations: 6 (1 + P) variables with
  :data:`TAYLOR_ORDER` + 1 Taylor coefficients in each of :data:`SIMD_WIDTH` batch lanes;
- normal matrices: A^T A of P x P numbers, :data:`NORMAL_COPIES` of them (the sums, the
  damped or regularised copy that is factorised, and its factor or eigenvectors);
- a candidate pool of ``select``: the predicted arcs of every candidate (19 numbers a sample:
  the arcs and the propagation's output) and one information matrix P x P per candidate;

Truth mascons need no estimate: k-means assigns the volume samples with a k-d tree (no
samples x mascons matrix), so their memory is that of the samples; their count is bounded by
the number of samples instead (:func:`hamgrav.bodies.interiors.compress`).
"""

from __future__ import annotations

import math
import re

from .errors import InputError

__all__ = [
    "MemoryLimit",
    "arcs_bytes",
    "campaign_bytes",
    "check_memory",
    "fit_bytes",
    "format_bytes",
    "memory_limit",
    "network_parameters",
    "parse_memory",
    "pool_bytes",
]

#: Bytes of one float64.
FLOAT = 8
#: Taylor order heyoka uses at hamgrav's tolerances (about 1e-14: order 20 or so).
TAYLOR_ORDER = 20
#: SIMD lanes of a batch integrator (AVX-512 doubles; 4 on AVX2, so an upper estimate).
SIMD_WIDTH = 8
#: P x P matrices a fit holds at once (see the module docstring).
NORMAL_COPIES = 3

_UNITS = {
    "": 1,
    "b": 1,
    "k": 10**3,
    "kb": 10**3,
    "m": 10**6,
    "mb": 10**6,
    "g": 10**9,
    "gb": 10**9,
    "t": 10**12,
    "tb": 10**12,
    "kib": 2**10,
    "mib": 2**20,
    "gib": 2**30,
    "tib": 2**40,
}


def parse_memory(text: str, option: str = "--max-memory") -> int:
    """Bytes of a memory size written as a number and a unit (``8GiB``, ``512MiB``, ``16GB``,
    ``1.5TiB``; no unit: bytes); :class:`InputError` naming ``option`` otherwise."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", text)
    unit = match.group(2).lower() if match else None
    if match is None or unit not in _UNITS:
        raise InputError(f"{option} must be a size such as 8GiB, 512MiB or 16GB, got {text!r}")
    value = float(match.group(1)) * _UNITS[unit]
    if not (math.isfinite(value) and value >= 1):
        raise InputError(f"{option} must be a positive size such as 8GiB, got {text!r}")
    return int(value)


def format_bytes(n: float) -> str:
    """A byte count in binary units to 3 digits (``32 TiB``, ``1.5 GiB``)."""
    for unit, size in (("PiB", 2**50), ("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n / 2**10:.3g} KiB"


class MemoryLimit:
    """The memory a job may use [bytes] and how to name it in an error (``source``)."""

    def __init__(self, limit: int, source: str):
        self.bytes = int(limit)
        self.source = source

    def __repr__(self) -> str:
        return f"MemoryLimit({self.bytes}, {self.source!r})"


def memory_limit(max_memory: str | None, option: str = "--max-memory") -> MemoryLimit:
    """``max_memory`` parsed (see :func:`parse_memory`), else the memory available now."""
    if max_memory is not None:
        return MemoryLimit(parse_memory(max_memory, option), f"{option} {max_memory.strip()}")
    import psutil

    available = psutil.virtual_memory().available
    return MemoryLimit(available, f"the {format_bytes(available)} of memory available")


def check_memory(job: str, parts: dict[str, float], limit: MemoryLimit, fix: str) -> None:
    """Refuse a job whose arrays (``parts``: what -> bytes) need more than ``limit``: one line
    naming the ``job``, the total, its largest part, the limit and the ``fix``."""
    total = float(sum(parts.values()))
    if total <= limit.bytes:
        return
    largest = max(parts, key=parts.get)
    raise InputError(
        f"{job} needs about {format_bytes(total)} of memory (of which {largest}: "
        f"{format_bytes(parts[largest])}), more than {limit.source}; {fix}, or pass "
        "--max-memory SIZE if more is free"
    )


# ------------------------------------------------------------------------------ estimates
def arcs_bytes(n_arcs: int, samples: int) -> float:
    """Times and noisy and true states of ``n_arcs`` arcs of ``samples`` samples [bytes]."""
    return 13.0 * n_arcs * samples * FLOAT


def campaign_bytes(
    orbits: int, arcs_per_orbit: int, samples_per_arc: int, check_points: int
) -> dict[str, float]:
    """The parts of a campaign's simulation [bytes]: its arcs and their pieces, and one orbit's
    propagation over its samples and ``check_points`` graze-check points."""
    samples = float(orbits) * arcs_per_orbit * samples_per_arc
    per_orbit = float(arcs_per_orbit) * samples_per_arc + check_points
    return {
        f"the arcs ({orbits} orbits x {arcs_per_orbit} arcs x {samples_per_arc} samples)": (
            arcs_bytes(1, samples) + 13.0 * samples * FLOAT
        ),
        "one orbit's propagation grid": 2 * 6.0 * per_orbit * FLOAT,
    }


def network_parameters(hidden, members: int = 1) -> int:
    """Weights and biases of ``members`` networks 3 -> hidden... -> 1 (the network term)."""
    sizes = (3, *(int(h) for h in hidden), 1)
    one = sum(a * b for a, b in zip(sizes[:-1], sizes[1:], strict=True)) + sum(sizes[1:])
    return members * one


def _design(chunk: int, samples: int, n_params: int) -> float:
    return 2.0 * chunk * samples * 6 * n_params * FLOAT


def _integrator(n_params: int) -> float:
    return 6.0 * (1 + n_params) * (TAYLOR_ORDER + 1) * SIMD_WIDTH * FLOAT


def fit_bytes(n_arcs: int, samples: int, n_params: int, chunk: int = 64) -> dict[str, float]:
    """The parts of a fit of ``n_params`` parameters to ``n_arcs`` arcs of ``samples`` samples,
    sensitivities computed ``chunk`` arcs at a time [bytes]."""
    p = float(n_params)
    return {
        "the arcs": arcs_bytes(n_arcs, samples),
        f"a design block ({min(chunk, n_arcs)} arcs x {samples} samples x 6 x {n_params} "
        "parameters)": _design(min(chunk, n_arcs), samples, n_params),
        "the variational integrator": _integrator(n_params),
        f"the normal matrices ({n_params} x {n_params})": NORMAL_COPIES * p * p * FLOAT,
    }


def pool_bytes(
    candidates: int, arcs_per_orbit: int, samples_per_arc: int, n_params: int, chunk: int = 64
) -> dict[str, float]:
    """The parts of a D-optimal choice from ``candidates`` orbits of ``arcs_per_orbit`` arcs of
    ``samples_per_arc`` samples under a model of ``n_params`` parameters [bytes]."""
    samples = float(candidates) * arcs_per_orbit * samples_per_arc
    p = float(n_params)
    return {
        f"the predicted arcs ({candidates} candidates x {arcs_per_orbit} arcs x "
        f"{samples_per_arc} samples)": 19.0 * samples * FLOAT,
        "a design block": _design(min(chunk, arcs_per_orbit), samples_per_arc, n_params),
        "the variational integrator": _integrator(n_params),
        f"the information matrices ({candidates} x {n_params} x {n_params})": (
            (candidates + NORMAL_COPIES) * p * p * FLOAT
        ),
    }

"""What every solver shares: the outcome of a solve, its result record, the abstract base."""

from __future__ import annotations

import enum
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from ..core.problem import ArcNormals, ArcProblem

__all__ = ["Outcome", "SolveResult", "Solver"]


class Outcome(enum.Enum):
    """How a solve ended."""

    CONVERGED = "converged"  #: the stopping test was met
    COMPLETED = "completed"  #: a fixed-length run (Adam) did all its steps
    ITERATION_CAP = "iteration cap"  #: stopped at the iteration cap before converging
    DAMPING_SATURATED = "damping saturated"  #: LM damping too large for any decrease
    NO_IMPROVEMENT = "no improvement"  #: the best iterate is the initial point
    DIVERGED = "diverged"  #: the iterates stopped propagating or became non-finite

    @property
    def ok(self) -> bool:
        """Whether the result can be used as a fit."""
        return self in (Outcome.CONVERGED, Outcome.COMPLETED, Outcome.ITERATION_CAP)


@dataclass(frozen=True, eq=False)
class SolveResult:
    """The result of a solve.

    Attributes:
        params: the returned parameters (the best-validation iterate when validation arcs
            were given, else the last accepted one).
        cost: training cost J = r.r / 2 at the last iterate (Adam: of the last mini-batch, per
            residual component).
        params_cost: the training arcs' cost J = r.r / 2 at ``params``, without the
            regulariser (``params`` is not the last iterate when the best-validation iterate
            is returned); None when the solver did not evaluate it on all training arcs (Adam
            works on mini-batches).
        initial_cost: training cost at the initial parameters (same normalisation).
        iterations: iterations (LM) or steps (Adam) run.
        best_iteration: iteration of ``params`` (0: the initial point).
        outcome: how the solve ended; ``message`` says it in words.
        history: per-iteration records (lists of numbers keyed by name).
        wall_s: wall time [s].
        solver: the solver's settings (plain data).
        normals: the training arcs' own sums (no regulariser) at ``params`` when the solver
            computed them there (LM): the fit diagnostics use their A^T A, and a warm-started
            fit on more arcs adds to them (``known`` of :meth:`Solver.solve`); not saved.
        members: the members' own results, for an ensemble fitted member by member.
    """

    params: np.ndarray
    cost: float
    initial_cost: float
    iterations: int
    best_iteration: int
    outcome: Outcome
    message: str
    history: dict = field(default_factory=dict)
    wall_s: float = 0.0
    solver: dict = field(default_factory=dict)
    normals: ArcNormals | None = field(default=None, repr=False, compare=False)
    members: tuple[SolveResult | None, ...] = field(default=(), repr=False, compare=False)
    params_cost: float | None = None

    @property
    def data_normal(self) -> np.ndarray | None:
        """The training arcs' own A^T A at ``params`` (None when the solver did not form it)."""
        return None if self.normals is None else self.normals.ata

    @property
    def converged(self) -> bool:
        """True when the solve ended normally (converged or a completed fixed-length run)."""
        return self.outcome in (Outcome.CONVERGED, Outcome.COMPLETED)

    def summary(self) -> dict:
        """Plain-data summary (no parameters, no history)."""
        return {
            "solver": self.solver.get("name"),
            "outcome": self.outcome.value,
            "message": self.message,
            "iterations": int(self.iterations),
            "best_iteration": int(self.best_iteration),
            "initial_cost": float(self.initial_cost),
            "cost": float(self.cost),
            "params_cost": None if self.params_cost is None else float(self.params_cost),
            "wall_s": round(float(self.wall_s), 3),
        }


class Solver(ABC):
    """A solver of the arc least-squares problem: a frozen dataclass of settings whose
    :meth:`solve` runs it. Every solver acts on an :class:`ArcProblem` only through its exact
    sensitivities, so comparisons never mix different gradient information."""

    name: str = "solver"

    def solve(
        self,
        problem: ArcProblem,
        theta0: np.ndarray | None = None,
        *,
        train: np.ndarray | None = None,
        validation: np.ndarray | None = None,
        callback: Callable[[int, dict], None] | None = None,
        checkpoint: Callable[[np.ndarray, dict], None] | None = None,
        resume: dict | None = None,
        known: ArcNormals | None = None,
    ) -> SolveResult:
        """Minimise the cost over the ``train`` arcs (all if None) from ``theta0`` (zeros if
        None).

        With ``validation`` arcs, the iterate with the lowest validation cost is returned.
        ``callback(iteration, record)`` reports progress; ``checkpoint(theta, state)`` is called
        with everything needed to continue, and passing that state back as ``resume`` (with
        theta as ``theta0``) continues the run. ``known``: sums of some of the training arcs
        at ``theta0`` (e.g. the previous stage's :attr:`SolveResult.normals`), which a solver
        forming normal equations adds to instead of recomputing them.
        """
        start = time.perf_counter()
        theta = np.zeros(problem.n_params) if theta0 is None else np.array(theta0, dtype=float)
        if validation is not None and len(validation) == 0:
            validation = None
        result = self._iterate(
            problem, theta, train, validation, callback, checkpoint, resume, known
        )
        return replace(result, wall_s=time.perf_counter() - start, solver=self.describe())

    @abstractmethod
    def _iterate(
        self, problem, theta, train, validation, callback, checkpoint, resume, known
    ) -> SolveResult:
        """The solver's iterations from ``theta`` (see :meth:`solve` for the arguments); the
        result's wall time and settings are filled in by :meth:`solve`."""

    def describe(self) -> dict:
        """The solver's name and settings (plain data)."""
        return {"name": self.name, **asdict(self)}

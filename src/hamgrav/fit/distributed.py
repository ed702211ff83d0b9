"""One fit's arcs on a Dask cluster: the sums over arcs computed by the workers.

A :class:`DistributedArcProblem` is an :class:`~hamgrav.core.problem.ArcProblem` whose sums
over arcs (costs, per-arc costs, the gradient A^T r and the normal equations A^T A, A^T r)
are computed by the workers of a ``dask.distributed`` Client, so that every solver, the
continual fits and the cross-validation run on a cluster unchanged:

- the arcs are split into contiguous chunks (by default two per worker), each shipped to the
  cluster once as a task of plain data (the chunk's arcs, the model's description and the
  problem's settings); a worker builds the chunk's problem once and keeps it, with the
  Taylor integrators in its own compile cache;
- each call sends the parameters and, per chunk, which of its arcs are asked for; a chunk
  comes back as its sums (cost and A^T r, and A^T A for the normal equations), computed 64
  arcs at a time as in-process, and the client adds them in chunk order, so the numbers do
  not depend on which worker finishes first and equal an in-process fit's to rounding;
- the regulariser (the harmonic penalty) stays on the client: its rows do not depend on the
  arcs.

Memory: the client holds the arcs (13 numbers a sample), the sum and one chunk's P x P at a
time; a worker its chunks' arcs, one design block of 64 arcs and one P x P per chunk (see
:mod:`hamgrav.sizing`). No array of arcs x samples x parameters is ever formed.

A worker lost mid-fit loses nothing the fit needs: the chunk's data is a task the scheduler
can run again on another worker (its problem is rebuilt and compiled there), and the call
waits for it. If the cluster cannot finish a call (every worker gone, a scheduler that
gives up on a chunk), the call raises :class:`~hamgrav.errors.DistributedError` and the fit
stops, keeping its last checkpoint (``--resume`` continues it).
"""

from __future__ import annotations

import uuid
from collections import OrderedDict

import numpy as np

from ..core.arcs import Arcs
from ..core.model import Model
from ..core.problem import ArcProblem
from ..errors import DistributedError, HamgravError, PropagationError

__all__ = ["DistributedArcProblem", "DistributedError", "NO_WORKERS_S", "default_chunks"]

#: Chunk problems a worker keeps (the oldest go first): the chunks of a few fits at once
#: (the members of an ensemble, cross-validation folds).
_KEPT_PROBLEMS = 64
_PROBLEMS: OrderedDict[str, ArcProblem] = OrderedDict()
#: A call gives up when the cluster has had no worker for this long [s].
NO_WORKERS_S = 120.0
#: How often a waiting call checks that the cluster still has workers [s].
_POLL_S = 10.0


def default_chunks(client, n_arcs: int) -> int:
    """Chunks of a fit's arcs on ``client``'s cluster: two per worker thread (so that a slow
    worker holds up only half of its share), at most one per arc."""
    threads = sum(client.nthreads().values()) or 1
    return max(1, min(n_arcs, 2 * threads))


# ------------------------------------------------------------------------------ worker side
def _chunk_data(token: str, model: dict, arcs: Arcs, settings: dict) -> dict:
    """The value of a chunk's task on the worker that holds it: plain data."""
    return {"token": token, "model": model, "arcs": arcs, "settings": settings}


def _problem_of(chunk: dict) -> ArcProblem:
    """The chunk's problem, built once per worker process."""
    problem = _PROBLEMS.get(chunk["token"])
    if problem is None:
        try:
            from dask.distributed import get_worker

            threads = get_worker().state.nthreads
        except (ImportError, ValueError, AttributeError):  # run outside a worker
            threads = 1
        model = Model.from_description(chunk["model"])
        problem = ArcProblem(model, chunk["arcs"], threads=threads, **chunk["settings"])
        _PROBLEMS[chunk["token"]] = problem
        while len(_PROBLEMS) > _KEPT_PROBLEMS:
            _PROBLEMS.popitem(last=False)
    _PROBLEMS.move_to_end(chunk["token"])
    return problem


def _chunk_sums(chunk: dict, theta: np.ndarray, local: np.ndarray, first: int, what: str):
    """One chunk's part of a call: ``what`` is "normals" (cost, A^T r, A^T A), "gradient"
    (cost, A^T r) or "arc_costs" (per-arc costs in the order of ``local``). ``first``: the
    global index of the chunk's first arc, for error messages."""
    problem = _problem_of(chunk)
    try:
        if what == "normals":
            return problem.normal_equations(theta, local, regularised=False)
        if what == "gradient":
            return problem.gradient(theta, local)
        return problem.arc_costs(theta, local)
    except PropagationError as exc:
        # the worker's arc numbers are the chunk's own: name the fit's
        raise PropagationError(f"{exc} (arc numbers counted from arc {first})") from None


# ------------------------------------------------------------------------------ client side
class DistributedArcProblem(ArcProblem):
    """An :class:`~hamgrav.core.problem.ArcProblem` whose sums over arcs run on ``client``'s
    cluster in ``chunks`` chunks of contiguous arcs (default :func:`default_chunks`); every
    other argument is the in-process problem's. ``predict``, ``residuals`` and ``design``
    (figures, diagnostics on a few arcs) run in-process."""

    def __init__(self, model: Model, arcs: Arcs, *, client, chunks: int | None = None, **kwargs):
        super().__init__(model, arcs, **kwargs)
        self.client = client
        n = default_chunks(client, arcs.n_arcs) if chunks is None else int(chunks)
        if not 1 <= n <= max(arcs.n_arcs, 1):
            raise ValueError(f"chunks must lie in [1, {arcs.n_arcs}], got {chunks}")
        self.bounds = np.linspace(0, arcs.n_arcs, n + 1).round().astype(int)
        settings = {
            "estimate_trajectory_params": self.estimate_trajectory_params,
            "trajectory_values": self.trajectory_values,
            "whitening": None if self.whitening is None else np.array(self.whitening),
            "tol": self.tol,
            "sensitivity_tol": self.sensitivity_tol,
            "max_steps": self.max_steps,
            "gradient_method": self.gradient_method,
        }
        description = model.describe()
        self._chunks = [
            client.submit(
                _chunk_data,
                f"{uuid.uuid4().hex}-{a}",
                description,
                arcs.subset(np.arange(a, b)),
                {
                    **settings,
                    "arc_weights": None
                    if self.arc_weights is None
                    else np.array(self.arc_weights[a:b]),
                },
                pure=False,
            )
            for a, b in zip(self.bounds[:-1], self.bounds[1:], strict=True)
        ]

    @property
    def n_chunks(self) -> int:
        """Chunks the arcs are split into."""
        return len(self._chunks)

    def _submit(self, theta, arc_indices, what: str) -> list:
        """(positions in the selection, future) per chunk holding selected arcs, chunk order."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_params,):
            raise ValueError(f"theta must have {self.n_params} entries, got {theta.shape}")
        idx = self._indices(arc_indices)
        chunk_of = np.searchsorted(self.bounds, idx, side="right") - 1
        calls = []
        for c in np.unique(chunk_of):
            where = np.flatnonzero(chunk_of == c)
            first = int(self.bounds[c])
            future = self.client.submit(
                _chunk_sums, self._chunks[c], theta, idx[where] - first, first, what, pure=False
            )
            calls.append((where, future))
        return calls

    def _result(self, future):
        """A chunk's result; the cluster's failures as one :class:`DistributedError`, and a
        cluster left with no worker for :data:`NO_WORKERS_S` seconds too (a scheduler waits
        for workers forever by default)."""
        from dask.distributed import TimeoutError as DaskTimeout

        try:
            idle = 0.0
            while True:
                try:
                    return future.result(timeout=_POLL_S)
                except (DaskTimeout, TimeoutError):
                    idle = idle + _POLL_S if not self.client.nthreads() else 0.0
                    if idle >= NO_WORKERS_S:
                        raise DistributedError(
                            f"the cluster has had no worker for {idle:.0f} s; start workers "
                            "(or use --workers N), then resume the fit"
                        ) from None
        except (PropagationError, HamgravError, ValueError):
            raise
        except Exception as exc:  # KilledWorker, CancelledError, lost connections...
            raise DistributedError(
                f"the cluster could not compute a chunk of arcs ({type(exc).__name__}: {exc}); "
                "check the workers, then resume the fit"
            ) from None
        finally:
            future.release()

    def normal_equations(self, theta, arc_indices=None, chunk: int = 64, *, regularised=True):
        """(J, A^T r, A^T A) summed over the chunks in chunk order; see
        :meth:`ArcProblem.normal_equations`."""
        n = self.n_params
        cost, atr, ata = 0.0, np.zeros(n), np.zeros((n, n))
        for _, future in self._submit(theta, arc_indices, "normals"):
            c, r, a = self._result(future)
            cost, atr, ata = cost + c, atr + r, ata + a
        if regularised:
            return self.regularise(theta, cost, atr, ata)
        return cost, atr, ata

    def gradient(self, theta, arc_indices=None, chunk: int = 64):
        """(J, A^T r) summed over the chunks in chunk order."""
        cost, atr = 0.0, np.zeros(self.n_params)
        for _, future in self._submit(theta, arc_indices, "gradient"):
            c, r = self._result(future)
            cost, atr = cost + c, atr + r
        return cost, atr

    def arc_costs(self, theta, arc_indices=None) -> np.ndarray:
        """r.r / 2 of each selected arc in the order given (see :meth:`ArcProblem.arc_costs`)."""
        out = np.zeros(len(self._indices(arc_indices)))
        for where, future in self._submit(theta, arc_indices, "arc_costs"):
            out[where] = self._result(future)
        return out

    def cost(self, theta, arc_indices=None) -> float:
        """J = r.r / 2 over the selected arcs, summed chunk by chunk in chunk order."""
        return float(
            sum(
                float(np.sum(self._result(future)))
                for _, future in self._submit(theta, arc_indices, "arc_costs")
            )
        )

"""Every propagation in hamgrav goes through this module (the only caller of heyoka's
``propagate_*``): fitted arcs with their sensitivities, predicted candidate arcs, the truth's
simulated tracking, descents to contact with the surface.

All inputs and outputs are canonical (length = synchronous radius, time = spin period / 2 pi)
and the integrators come from the one compile cache of :mod:`hamgrav.core.model`.

- :func:`propagate_batch`: many trajectories, each from its own start time to its own time
  grid, in SIMD batches over threads, optionally with d state / d runtime-parameters.
- :func:`adjoint_gradient`: the cost of many arcs and its gradient with respect to the
  runtime parameters, by the adjoint method (the costate from the state transition matrix,
  the parameter rates integrated at a few nodes per arc): no sensitivity to the parameters.
- :func:`propagate_scalar`: one trajectory to a time grid (long truth propagations).
- :func:`propagate_to_contact`: one trajectory until it crosses a closed surface.
- :func:`state_transition`: d state(t_k) / d state(t_0) along trajectories (first-order
  variational equations with respect to the initial state).
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import heyoka as hy
import numpy as np

from .geometry import points_inside
from .model import DEFAULT_FIT_TOLERANCE, Model, compiled_integrators

__all__ = [
    "ADJOINT_TOLERANCE",
    "AdjointGradient",
    "BatchPropagation",
    "adjoint_gradient",
    "Touchdown",
    "propagate_batch",
    "propagate_scalar",
    "propagate_to_contact",
    "state_transition",
]


class _StepLimit:
    """Step callback stopping a propagation after ``limit`` Taylor steps: a well-posed arc takes
    a few steps, so a runaway count means the parameters make the dynamics stiff or singular
    (a solver then rejects the trial instead of waiting on it)."""

    def __init__(self, limit: int | None):
        self.limit = limit
        self.steps = 0
        self.exceeded = False

    def __call__(self, ta) -> bool:
        self.steps += 1
        if self.limit is not None and self.steps > self.limit:
            self.exceeded = True
            return False
        return True


@dataclass(frozen=True)
class BatchPropagation:
    """Result of :func:`propagate_batch`.

    Attributes:
        states: (n, m, 6) canonical states at the grid times (NaN where ``ok`` is False).
        sensitivities: (n, m, 6, n_par) d state / d runtime parameter, or None.
        ok: (n,) whether each trajectory reached its last time with finite states.
        exceeded_steps: (n,) whether a trajectory's batch hit the Taylor-step limit.
    """

    states: np.ndarray
    sensitivities: np.ndarray | None
    ok: np.ndarray
    exceeded_steps: np.ndarray


#: Propagation threads of this process, by pool size, started once: starting them on every
#: call took about 3 % of a 112-arc network fit (two thread starts per call, 366 in the fit).
_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def _forget_pools() -> None:
    # a forked child inherits the pools but not their threads
    _POOLS.clear()


os.register_at_fork(after_in_child=_forget_pools)


def _thread_pool(n_threads: int) -> ThreadPoolExecutor:
    """The process's pool of ``n_threads`` propagation threads."""
    with _POOLS_LOCK:
        if n_threads not in _POOLS:
            _POOLS[n_threads] = ThreadPoolExecutor(n_threads, "hamgrav-propagate")
        return _POOLS[n_threads]


def propagate_batch(
    model: Model,
    states0: np.ndarray,
    times: np.ndarray,
    runtime_params: np.ndarray | None = None,
    *,
    sensitivities: bool = False,
    tol: float = DEFAULT_FIT_TOLERANCE,
    threads: int | None = None,
    max_steps: int | None = None,
) -> BatchPropagation:
    """Propagate ``states0`` (n, 6), each given at ``times[i, 0]``, to the grids ``times``
    (n, m), increasing along each row, under ``model``.

    ``runtime_params`` (n_system_params, n) holds each trajectory's runtime parameters (see
    :mod:`hamgrav.core.model`). Trajectories go in SIMD batches (the last batch padded by
    repeating its last member) shared out over ``threads`` copies of the compiled integrator
    (heyoka's ``ensemble_propagate_grid_batch`` would copy the integrator once per batch on
    every call; these copies are made once per process and kept in the compile cache).
    ``max_steps`` caps the Taylor steps per batch (None: no cap).
    """
    states0 = np.asarray(states0, dtype=float)
    times = np.asarray(times, dtype=float)
    n, n_m = times.shape
    n_sys = model.n_system_params
    if states0.shape != (n, 6):
        raise ValueError(f"states0 must be ({n}, 6), got {states0.shape}")
    if runtime_params is None:
        runtime_params = np.zeros((n_sys, n))
    runtime_params = np.asarray(runtime_params, dtype=float).reshape(n_sys, n)
    variational = sensitivities and n_sys > 0
    compiled = compiled_integrators(model, variational=variational, tol=tol)
    width = compiled.integrators[0].batch_size
    chunks = [np.arange(i, min(i + width, n)) for i in range(0, n, width)]
    n_threads = max(1, min(int(threads or os.cpu_count() or 1), len(chunks)))

    # rows of trajectories that fail are set to NaN below; the others are written whole
    states = np.empty((n, n_m, 6))
    jac = np.empty((n, n_m, 6, n_sys)) if variational else None
    ok = np.zeros(n, bool)
    exceeded = np.zeros(n, bool)

    def work(ta, worker: int):
        for c in range(worker, len(chunks), n_threads):
            sel = chunks[c]
            pad = np.concatenate([sel, np.repeat(sel[-1:], width - len(sel))])
            ta.set_time(times[pad, 0].copy())
            st = ta.state
            st[:] = 0.0
            st[:6] = states0[pad].T
            if n_sys:
                ta.pars[:] = runtime_params[:, pad]
            limit = _StepLimit(max_steps)
            res = ta.propagate_grid(np.ascontiguousarray(times[pad].T), callback=limit)
            grid_states = res[-1]  # (m reached, n_state, width)
            if limit.exceeded:
                exceeded[sel] = True
                continue
            if grid_states.shape[0] != n_m:
                continue
            good = np.all(np.isfinite(grid_states[:, :, : len(sel)]), axis=(0, 1))
            ok[sel] = good
            states[sel] = np.transpose(grid_states[:, :6, : len(sel)], (2, 0, 1))
            if variational:
                sens = grid_states[:, 6:, : len(sel)].reshape(n_m, 6, n_sys, len(sel))
                jac[sel] = np.transpose(sens, (3, 0, 1, 2))

    _over_threads(compiled, n_threads, work)
    states[~ok] = np.nan
    if jac is not None:
        jac[~ok] = np.nan
    if sensitivities and jac is None:
        jac = np.zeros((n, n_m, 6, 0))
    return BatchPropagation(states, jac, ok, exceeded)


def _over_threads(compiled, n_threads: int, work) -> None:
    """Run ``work(integrator, worker)`` for workers 0..n_threads-1, each on its own copy of
    the compiled integrator, holding the set's lock."""
    with compiled.lock:
        integrators = compiled.take(n_threads)
        if n_threads == 1:
            work(integrators[0], 0)
        else:
            pool = _thread_pool(n_threads)
            futures = [pool.submit(work, integrators[w], w) for w in range(n_threads)]
            for f in futures:
                f.result()


@dataclass(frozen=True)
class AdjointGradient:
    """Result of :func:`adjoint_gradient`.

    Attributes:
        costs: (n,) each arc's cost 0.5 w |W (y - x)|^2 (canonical, or dimensionless when
            whitened; w the arc's weight, 1 without weights); NaN for an arc whose forward
            or costate pass failed.
        gradient: (n_system_params,) d (sum of the costs) / d runtime parameters, summed over
            the arcs that propagated (per-trajectory parameters: their sum too, see
            ``per_arc``).
        per_arc: (n, n_system_params - n_shared) the per-trajectory parameters' part of each
            arc's gradient (columns from ``n_shared`` on), for the caller to scatter.
        ok, exceeded_steps: (n,) as in :class:`BatchPropagation` (an arc is ok when both its
            forward pass and its costate pass ended well).
    """

    costs: np.ndarray
    gradient: np.ndarray
    per_arc: np.ndarray
    ok: np.ndarray
    exceeded_steps: np.ndarray


#: Tolerance of the costate pass (the state and its transition matrix, 42 variables, over
#: each whole arc). The costs come from the forward pass at the fit's tolerance; only the
#: gradient depends on this one: on the 112 Itokawa arcs (bench/gradient.py) it agrees with
#: the forward sensitivities' to 5e-12 relative at 1e-7 (2e-12 at 1e-8, 5e-10 at 1e-6), and
#: 1e-7 takes 0.8-0.9 of 1e-8's time.
ADJOINT_TOLERANCE = 1e-7
#: Gauss-Legendre nodes per segment of an arc, at which the parameter rates are evaluated
#: (see :func:`_arc_nodes`).
ADJOINT_SEGMENT_NODES = 8
#: Longest segment of an arc, in radians of the fastest motion along it (see
#: :func:`_arc_nodes`); the interpolation's error falls as its eighth power. On the tests'
#: arcs of 1.7 rad (prograde and retrograde) the gradient agrees with the forward one to
#: 1e-10 (networks) and 6e-11 (SH of degree 3-24), as the quadrature interval by interval
#: between samples that this replaced did.
ADJOINT_SEGMENT_PHASE = 0.1
#: Node weights (floats) formed for all arcs at once before the costate pass; beyond this
#: (many long arcs of many samples) they are formed batch by batch (64 MB).
_NODE_WEIGHTS_AT_ONCE = 8_000_000


def _lagrange_in_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(the n Gauss-Legendre nodes u_i on [-1, 1], B (n, n)): the Lagrange polynomial of node
    i is L_i(u) = sum_k B[i, k] P_k(u) (the quadrature integrates P_k P_l exactly for
    k + l <= 2n - 1, so the interpolant at its nodes has these Legendre coefficients)."""
    nodes, weights = np.polynomial.legendre.leggauss(n)
    legendre = np.polynomial.legendre.legvander(nodes, n - 1)  # P_k(u_i)
    return nodes, weights[:, None] * (2 * np.arange(n) + 1) / 2 * legendre


def _legendre_integrals(u: np.ndarray, n: int) -> np.ndarray:
    """F_k(u) = integral of P_k from -1 to u, k < n, shape (*u.shape, n)."""
    p = np.polynomial.legendre.legvander(u, n)
    out = np.empty((*np.shape(u), n))
    out[..., 0] = u + 1.0
    k = np.arange(1, n)
    out[..., 1:] = (p[..., 2:] - p[..., :-2]) / (2 * k + 1)
    return out


def _motion_rate(states: np.ndarray) -> np.ndarray:
    """The fastest canonical rate of each arc's motion (n,), from its states (n, m, 6) in the
    rotating frame: the largest of the spin's (1), the orbit's at the arc's smallest radius
    (r^-3/2) and the angular rate of its track over the body, |q x dq/dt| / |q|^2 (a
    retrograde orbit's is near its orbital rate plus the spin's)."""
    q, p = states[..., :3], states[..., 3:]
    # dq/dt = p - omega x q with omega = z: (p_x + q_y, p_y - q_x, p_z)
    velocity = np.stack([p[..., 0] + q[..., 1], p[..., 1] - q[..., 0], p[..., 2]], axis=-1)
    r2 = np.sum(q * q, axis=-1)
    track = np.linalg.norm(np.cross(q, velocity), axis=-1) / r2
    rate = np.maximum(r2**-0.75, track).max(axis=1)
    return np.where(np.isfinite(rate), np.maximum(1.0, rate), 1.0)


def _segment_counts(times: np.ndarray, states: np.ndarray) -> np.ndarray:
    """Segments (n,) of each arc's interpolation (:func:`_arc_nodes`)."""
    span = times[:, -1] - times[:, 0]
    rate = _motion_rate(states)
    return np.maximum(np.ceil(span * rate / ADJOINT_SEGMENT_PHASE), 1).astype(int)


def _arc_nodes(
    times: np.ndarray, states: np.ndarray, segments: np.ndarray | None = None
) -> list[tuple]:
    """The nodes of each arc (samples at ``times`` (n, m), m >= 2; ``states`` (n, m, 6)) for
    the integral of the parameter rates, and the weights that fold the costate into them.

    Between samples t_k and t_k+1 the costate is lam(t) = Phi(t)^-T c_k with c_k constant
    (:func:`adjoint_gradient`), so the gradient is sum_k integral over [t_k, t_k+1] of
    M(t) c_k, with M(t) = (df/dp)^T Phi(t)^-T smooth over the whole arc (the jumps are all
    in c). The arc is cut into equal segments, as many as it needs for each to span at most
    :data:`ADJOINT_SEGMENT_PHASE` of the arc's fastest motion (``segments``, default
    :func:`_segment_counts`), and M is interpolated on each segment at
    :data:`ADJOINT_SEGMENT_NODES` Gauss-Legendre nodes tau_i (Lagrange polynomials L_i). The
    integral is then sum_i M(tau_i) d_i with d_i = sum_k c_k (integral of L_i over
    [t_k, t_k+1] within the segment): one evaluation of the rates per node, at the costate
    Phi(tau_i)^-T d_i, whatever the number of samples. An arc's nodes depend on that arc
    alone.

    Returns, per arc, (node times (K,), weights (K, m - 1): d = weights @ c)."""
    n_nodes = ADJOINT_SEGMENT_NODES
    unit_nodes, basis = _lagrange_in_legendre(n_nodes)
    start, span = times[:, 0], times[:, -1] - times[:, 0]
    if segments is None:
        segments = _segment_counts(times, states)
    out: list = [None] * len(times)
    for count in np.unique(segments):
        arcs = np.flatnonzero(segments == count)
        width = span[arcs] / count  # (a,)
        left = start[arcs][:, None] + width[:, None] * np.arange(count)  # (a, S)
        # the samples in each segment's variable u in [-1, 1], clipped to the segment
        u = 2.0 * (times[arcs][:, None, :] - left[..., None]) / width[:, None, None] - 1.0
        integrals = _legendre_integrals(np.clip(u, -1.0, 1.0), n_nodes)  # (a, S, m, n)
        within = np.diff(integrals, axis=2)  # (a, S, m - 1, n): each interval's part
        weights = 0.5 * width[:, None, None, None] * np.einsum("in,askn->asik", basis, within)
        weights = weights.reshape(len(arcs), count * n_nodes, -1)
        node_times = (left[..., None] + 0.5 * width[:, None, None] * (unit_nodes + 1.0)).reshape(
            len(arcs), -1
        )
        for row, arc in enumerate(arcs):
            out[arc] = (node_times[row], weights[row])
    return out


def _batch_grid(times: np.ndarray, arc_nodes: list) -> tuple:
    """The grid of one SIMD batch (``times`` (w, m) of its lanes' arcs and their
    :func:`_arc_nodes`): every lane's samples and nodes in time order, the lanes with fewer
    nodes padded with nodes of weight 0 apart from their samples and nodes, so that all
    lanes share one grid length. Returns (grid (w, m + k), node weights (w, k, m - 1), the
    samples' and the nodes' places in the grid (w, m), (w, k))."""
    w, m = times.shape
    k = max(len(t) for t, _ in arc_nodes)
    node_times, weights = np.empty((w, k)), np.zeros((w, k, m - 1))
    for lane, (t, wt) in enumerate(arc_nodes):
        n = len(t)
        node_times[lane, :n], weights[lane, :n] = t, wt
        if n < k:  # inside the widest gap between the lane's samples and nodes: apart from all
            points = np.sort(np.concatenate([times[lane], t]))
            gap = int(np.argmax(np.diff(points)))
            fraction = np.arange(1, k - n + 1) / (k - n + 1)
            node_times[lane, n:] = points[gap] + (points[gap + 1] - points[gap]) * fraction
    # a sample sorts before a node at the same time (stable)
    order = np.argsort(np.concatenate([times, node_times], axis=1), axis=1, kind="stable")
    grid = np.take_along_axis(np.concatenate([times, node_times], axis=1), order, axis=1)
    place = np.argsort(order, axis=1)
    return grid, weights, place[:, :m], place[:, m:]


def adjoint_gradient(
    model: Model,
    states0: np.ndarray,
    times: np.ndarray,
    observed: np.ndarray,
    runtime_params: np.ndarray,
    *,
    n_shared: int,
    whitening: np.ndarray | None = None,
    arc_weights: np.ndarray | None = None,
    tol: float = DEFAULT_FIT_TOLERANCE,
    adjoint_tol: float | None = None,
    threads: int | None = None,
    max_steps: int | None = None,
) -> AdjointGradient:
    """The cost 0.5 sum_k w_k |W (y - x)|^2 of arcs started at ``states0`` (n, 6) on the
    grids ``times`` (n, m) against ``observed`` states y (n, m, 6), and its gradient with
    respect to the runtime parameters (n_system_params, n), by the adjoint method; w_k are the
    ``arc_weights`` (n,) (1 when not given), W the ``whitening`` (identity when not given).

    The states come forward at ``tol`` (:func:`propagate_batch`), giving the costs and the
    costate's jumps dJ/dx_k at the samples. The costate lam' = -(df/dx)^T lam is linear, so
    between samples t_k and t_k+1 it is lam(t) = Phi(t)^-T sum_{j > k} Phi(t_j)^T dJ/dx_j,
    with Phi the state transition matrix from the arc's start (symplectic, so inverted by
    transposition: the dynamics are Hamilton's equations in canonical coordinates). One
    forward pass of the state and Phi (42 variables, at ``adjoint_tol``, default
    :data:`ADJOINT_TOLERANCE`) over each whole arc gives them at every sample and at the
    integral's nodes (dense output: the steps are not cut at the samples).
    The gradient is the integral of (df/dp)^T lam: (df/dp)^T Phi^-T, smooth over the arc,
    is interpolated on segments of it (:func:`_arc_nodes`), which leaves one evaluation of
    :func:`hamgrav.core.model.parameter_rate_function` (one reverse sweep of lam . f) per
    node, a few per radian of motion, not per interval between samples.
    Memory: the states, and per thread one SIMD batch's 42 variables at the samples and
    nodes and their rates (n_system_params per node); never a sensitivity per sample. The
    first ``n_shared`` runtime parameters are shared by all arcs (their gradients summed);
    the rest are per arc (returned in ``per_arc``)."""
    from .model import parameter_rate_function

    times = np.asarray(times, dtype=float)
    observed = np.asarray(observed, dtype=float)
    n, n_m = times.shape
    runtime_params = np.asarray(runtime_params, dtype=float).reshape(model.n_system_params, n)
    forward = propagate_batch(
        model, states0, times, runtime_params, tol=tol, threads=threads, max_steps=max_steps
    )
    residual = observed - forward.states
    whitened = residual if whitening is None else residual @ whitening.T
    if arc_weights is not None:
        whitened = whitened * np.sqrt(np.asarray(arc_weights, dtype=float))[:, None, None]
    costs = 0.5 * np.sum(whitened * whitened, axis=(1, 2))
    # dJ/dx_k = -w W^T W (y_k - x_k), as rows
    kicks = -(whitened if whitening is None else whitened @ whitening)
    if arc_weights is not None:
        kicks *= np.sqrt(np.asarray(arc_weights, dtype=float))[:, None, None]
    n_par = model.n_system_params
    per_arc = np.zeros((n, n_par - n_shared))
    ok = forward.ok.copy()
    exceeded = forward.exceeded_steps.copy()
    # each chunk's sum of the shared gradient, added up in a fixed order at the end: the
    # threads finish in any order, and a sum must not depend on it
    partial: dict[int, np.ndarray] = {}
    lock = threading.Lock()
    rates = parameter_rate_function(model)
    n_rate_pars = rates.nparams  # a cfunc counts parameters up to the last one it uses
    # the nodes of all arcs at once (numpy's cost is per call, not per arc) when their
    # weights (nodes x intervals per arc) are small; otherwise batch by batch, as they run
    arc_nodes: list | None = None
    if n_m > 1 and forward.ok.any():
        good = np.flatnonzero(forward.ok)
        segments = _segment_counts(times[good], forward.states[good])
        if segments.sum() * ADJOINT_SEGMENT_NODES * (n_m - 1) <= _NODE_WEIGHTS_AT_ONCE:
            arc_nodes = [None] * n
            formed = _arc_nodes(times[good], forward.states[good], segments)
            for i, nodes in zip(good, formed, strict=True):
                arc_nodes[i] = nodes

    def gradient_of(ta, sel: np.ndarray):
        """(the lanes' gradients (n_par, len(sel)), which lanes ended well, whether the step
        limit stopped them)."""
        width, lanes = ta.batch_size, len(sel)
        pad = np.concatenate([sel, np.repeat(sel[-1:], width - lanes)])
        ta.set_time(times[pad, 0].copy())
        st = ta.state
        st[:6] = states0[pad].T
        st[6:] = np.eye(6).reshape(36, 1)
        ta.pars[:] = runtime_params[:, pad]
        if arc_nodes is None:
            nodes = _arc_nodes(times[sel], forward.states[sel])
        else:
            nodes = [arc_nodes[i] for i in sel]
        grid, node_weights, at_sample, at_node = _batch_grid(
            times[pad], nodes + [nodes[-1]] * (width - lanes)
        )
        n_nodes = node_weights.shape[1]
        limit = _StepLimit(max_steps)
        out = ta.propagate_grid(np.ascontiguousarray(grid.T), callback=limit)[-1]
        if limit.exceeded or out.shape[0] != grid.shape[1]:
            return None, np.zeros(lanes, bool), limit.exceeded
        out = out[..., :lanes].transpose(2, 0, 1)  # (lanes, grid, 42)

        def at(places):
            if (places == places[0]).all():  # one layout for every lane: plain indexing
                return out[:, places[0]]
            return np.take_along_axis(out, places[:lanes, :, None], axis=1)

        samples, at_nodes = at(at_sample), at(at_node)
        phi_samples = samples[..., 6:].reshape(lanes, n_m, 6, 6)
        phi_nodes = at_nodes[..., 6:].reshape(lanes, n_nodes, 6, 6)
        jumps = np.einsum("lkij,lki->lkj", phi_samples, kicks[sel])  # Phi_k^T dJ/dx_k
        after = np.cumsum(jumps[:, ::-1], axis=1)[:, ::-1][:, 1:]  # sum over j > k
        # each node's share of the costate (see _arc_nodes): d_i = sum_k W_ik c_k
        c = np.matmul(node_weights[:lanes], after)  # (lanes, nodes, 6)
        # Phi is symplectic (Hamilton's equations in canonical (q, p)): Phi^-T = -J Phi J,
        # so lam = Phi^-T d is (-v_p, v_q) for v = Phi (d_p, -d_q), with no solve
        v = np.einsum("lnij,lnj->lni", phi_nodes, np.concatenate([c[..., 3:], -c[..., :3]], -1))
        lam = np.concatenate([-v[..., 3:], v[..., :3]], axis=-1)
        points = np.concatenate([at_nodes[..., :6], lam], axis=-1).reshape(-1, 12).T
        node_times = np.take_along_axis(grid, at_node, axis=1)
        extra = {"time": node_times[:lanes].ravel()} if rates.is_time_dependent else {}
        if n_rate_pars:
            extra["pars"] = np.repeat(runtime_params[:n_rate_pars, sel], n_nodes, axis=1)
        values = rates(np.ascontiguousarray(points), batch_parallel=False, **extra)
        gradient = -values.reshape(-1, lanes, n_nodes).sum(axis=2)
        return (
            gradient,
            np.all(np.isfinite(gradient), axis=0) & np.all(np.isfinite(lam), axis=(1, 2)),
            False,
        )

    pending = np.flatnonzero(forward.ok)
    adjoint_tol = ADJOINT_TOLERANCE if adjoint_tol is None else adjoint_tol
    compiled = compiled_integrators(model, variational=True, wrt="state", tol=adjoint_tol)
    width = compiled.integrators[0].batch_size
    chunks = [pending[i : i + width] for i in range(0, len(pending), width)]
    if chunks and n_m > 1:
        n_threads = max(1, min(int(threads or os.cpu_count() or 1), len(chunks)))

        def work(ta, worker):
            for c in range(worker, len(chunks), n_threads):
                sel = chunks[c]
                gradient, good, stopped = gradient_of(ta, sel)
                with lock:
                    ok[sel] &= good
                    exceeded[sel] |= stopped
                    if gradient is not None:
                        per_arc[sel] = gradient[n_shared:].T
                        partial[c] = gradient[:n_shared, good].sum(axis=1)

        _over_threads(compiled, n_threads, work)
    gradient = np.zeros(n_par)
    for key in sorted(partial):
        gradient[:n_shared] += partial[key]
    per_arc[~ok] = 0.0
    gradient[n_shared:] = per_arc[ok].sum(axis=0)
    costs[~ok] = np.nan
    return AdjointGradient(costs, gradient, per_arc, ok, exceeded)


def propagate_scalar(
    model: Model,
    state0: np.ndarray,
    times: np.ndarray,
    params: np.ndarray | None = None,
    *,
    t0: float = 0.0,
    tol: float = DEFAULT_FIT_TOLERANCE,
) -> tuple[np.ndarray, bool]:
    """Propagate one canonical state from ``t0`` to the increasing ``times`` under ``model``
    with runtime parameters ``params`` (n_system_params,).

    Returns ``(states, ok)``: states (len(times), 6), NaN after a failure, and whether the
    integration reached the last time.
    """
    times = np.asarray(times, dtype=float)
    out = np.full((len(times), 6), np.nan)
    if len(times) == 0:
        return out, True
    compiled = compiled_integrators(model, batch=False, tol=tol)
    with compiled.lock:
        ta = compiled.integrators[0]
        _set_scalar(ta, model, state0, t0, params)
        if times[0] != t0:
            res = ta.propagate_grid(np.concatenate([[t0], times]))
            states = res[-1][1:]
        else:
            res = ta.propagate_grid(times)
            states = res[-1]
    n = len(states)
    out[:n] = states
    return out, bool(res[0] == hy.taylor_outcome.time_limit and n == len(times))


def state_transition(
    model: Model,
    states0: np.ndarray,
    times: np.ndarray,
    runtime_params: np.ndarray | None = None,
    *,
    tol: float = DEFAULT_FIT_TOLERANCE,
) -> np.ndarray:
    """Phi (n, m, 6, 6) = d state(times[i, k]) / d state(times[i, 0]) for the trajectories
    starting at ``states0`` (n, 6) at ``times[:, 0]``, runtime parameters (n_system_params, n);
    canonical, Phi[i, 0] = identity. NaN rows for a trajectory that does not reach its last
    time. One compiled scalar integrator (heyoka ``var_ode_sys`` with respect to the state
    variables), from the compile cache like the others."""
    states0 = np.asarray(states0, dtype=float)
    times = np.asarray(times, dtype=float)
    n, n_m = times.shape
    n_sys = model.n_system_params
    if runtime_params is None:
        runtime_params = np.zeros((n_sys, n))
    runtime_params = np.asarray(runtime_params, dtype=float).reshape(n_sys, n)
    compiled = compiled_integrators(model, variational=True, wrt="state", batch=False, tol=tol)
    out = np.full((n, n_m, 6, 6), np.nan)
    identity = np.eye(6).ravel()
    with compiled.lock:
        ta = compiled.integrators[0]
        for i in range(n):
            ta.time = float(times[i, 0])
            ta.state[:6] = states0[i]
            ta.state[6:] = identity
            if n_sys:
                ta.pars[:] = runtime_params[:, i]
            res = ta.propagate_grid(np.ascontiguousarray(times[i]))
            grid = res[-1]
            if len(grid) == n_m and np.all(np.isfinite(grid)):
                out[i] = grid[:, 6:].reshape(n_m, 6, 6)
    return out


def _set_scalar(ta, model: Model, state0, t0: float, params) -> None:
    ta.time = float(t0)
    ta.state[:] = np.asarray(state0, dtype=float)
    if model.n_system_params:
        ta.pars[:] = np.asarray(params, dtype=float)


@dataclass(frozen=True)
class Touchdown:
    """Outcome of one descent: ``landed``, contact ``time`` and ``point`` (canonical); for a
    descent that did not land, where it stopped and the ``reason`` (escaped, diverged, timed
    out)."""

    landed: bool
    time: float
    point: np.ndarray
    reason: str = ""


def propagate_to_contact(
    model: Model,
    state0: np.ndarray,
    triangles: np.ndarray,
    *,
    params: np.ndarray | None = None,
    check_step: float,
    duration: float,
    escape_radius: float,
    contact_tol: float,
    t0: float = 0.0,
    bound_radius: float | None = None,
    max_steps_per_chunk: int = 20_000,
    tol: float = DEFAULT_FIT_TOLERANCE,
) -> Touchdown:
    """Propagate ``state0`` under ``model`` until it enters the closed surface ``triangles``
    (f, 3, 3), all canonical.

    The grid of step ``check_step`` is scanned for the first sample inside the surface (only
    samples within the surface's bounding radius are tested); the contact time is then refined
    by bisection to ``contact_tol``. Leaving ``escape_radius``, a non-finite state or more than
    ``max_steps_per_chunk`` Taylor steps per 200 samples stops the descent as "escaped" or
    "diverged"; reaching ``t0 + duration`` as "timed out". ``bound_radius`` (the largest
    distance of the surface from the origin) is computed from ``triangles`` when not given.
    """
    r_bound = bound_radius
    if r_bound is None:
        r_bound = float(np.linalg.norm(np.asarray(triangles).reshape(-1, 3), axis=1).max())
    compiled = compiled_integrators(model, batch=False, tol=tol)
    t_end = t0 + duration
    grid = np.arange(t0, t_end + check_step, check_step)
    chunk = 200
    with compiled.lock:
        ta = compiled.integrators[0]
        _set_scalar(ta, model, state0, t0, params)
        prev_t, prev_state = t0, np.array(state0, dtype=float)
        for start in range(0, len(grid), chunk):
            times = grid[start : start + chunk + 1]
            if len(times) < 2:
                break
            ta.time = prev_t
            ta.state[:] = prev_state
            limit = _StepLimit(max_steps_per_chunk)
            res = ta.propagate_grid(times, callback=limit)
            states = res[-1]
            n_ok = len(states)
            if limit.exceeded:
                return Touchdown(False, float(times[max(n_ok - 1, 0)]), prev_state[:3], "diverged")
            finite = np.all(np.isfinite(states), axis=1)
            r = np.linalg.norm(states[:, :3], axis=1)
            close = np.flatnonzero(finite & (r < r_bound))
            inside = np.zeros(n_ok, bool)
            if len(close):
                inside[close] = points_inside(triangles, states[close, :3])
            hit = np.flatnonzero(inside)
            bad = np.flatnonzero(~finite | (r > escape_radius))
            first_bad = bad[0] if len(bad) else n_ok
            if len(hit) and hit[0] < first_bad:
                k = hit[0]
                return _refine_contact(
                    ta, times[k - 1], states[k - 1], times[k], triangles, contact_tol
                )
            if len(bad):
                reason = "escaped" if np.isfinite(r[first_bad]) else "diverged"
                return Touchdown(False, float(times[first_bad]), states[first_bad, :3], reason)
            if res[0] != hy.taylor_outcome.time_limit or n_ok < len(times):
                return Touchdown(False, float(times[n_ok - 1]), states[n_ok - 1, :3], "diverged")
            prev_t, prev_state = times[-1], states[-1].copy()
            if prev_t >= t_end:
                break
    return Touchdown(False, float(prev_t), prev_state[:3], "timed out")


def _refine_contact(ta, t_out, state_out, t_in, triangles, contact_tol) -> Touchdown:
    """Bisect the contact time between an outside and an inside sample."""
    lo, hi = float(t_out), float(t_in)
    lo_state = np.array(state_out, dtype=float)
    while hi - lo > contact_tol:
        mid = 0.5 * (lo + hi)
        ta.time = lo
        ta.state[:] = lo_state
        ta.propagate_until(mid)
        if points_inside(triangles, ta.state[None, :3].copy())[0]:
            hi = mid
        else:
            lo, lo_state = mid, ta.state.copy()
    return Touchdown(True, hi, lo_state[:3].copy(), "")

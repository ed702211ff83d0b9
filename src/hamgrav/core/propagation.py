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

import functools
import hashlib
import os
import threading
from collections import OrderedDict
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


def _propagate_grid(ta, grid: np.ndarray, max_steps: int | None) -> tuple[np.ndarray, bool]:
    """``ta.propagate_grid(grid)`` of a batch integrator, stopped after ``max_steps`` Taylor
    steps (None: no cap):
    a well-posed arc takes a few steps, so a runaway count means the parameters make the
    dynamics stiff or singular (a solver then rejects the trial instead of waiting on it).
    Returns (the states at the grid, whether the cap stopped it). The cap is heyoka's own: a
    Python step callback would take the GIL at every step and serialise the threads that
    share out the batches."""
    res = ta.propagate_grid(grid, max_steps=0 if max_steps is None else int(max_steps))
    exceeded = any(o[0] == hy.taylor_outcome.step_limit for o in ta.propagate_res)
    return res[-1], exceeded


_TIME_LIMIT = hy.taylor_outcome.time_limit


def _propagate_lanes(
    ta, grid: np.ndarray, prepare, max_steps: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """The states (lanes, m, n_state) of a batch integrator's lanes at their ``grid``
    (lanes, m), increasing from each lane's start, over ``lanes / batch_size`` batches:
    ``prepare(b)`` sets the integrator's time, state and parameters for batch b (lanes
    b * batch_size on). Also returns whether ``max_steps`` Taylor steps (None: no cap)
    stopped each lane's batch (its states are then NaN), as :func:`_propagate_grid`.

    A batch whose lanes each reach the end of their grid in one Taylor step (the usual
    costate pass: its tolerance is loose and its arcs short) is propagated by heyoka's
    ``propagate_until`` keeping that step's Taylor coefficients, and the grid's points of
    all such batches are then the polynomials' values, one matrix product of the powers of
    t - t_start by the coefficients: ``propagate_grid``'s dense output to rounding, which
    it evaluates point by point, in as long as the step itself for 42 variables at 50
    points. A batch that needs more steps (its first is tried with a cap of one), or
    fails, goes again through :func:`_propagate_grid` (once most batches have needed more,
    the rest go there directly). ``step`` would give every step's coefficients, but it holds
    the GIL; ``propagate_until`` releases it, so threads propagate side by side."""
    n_lanes, m = grid.shape
    width, order, dim = ta.batch_size, ta.order, ta.dim
    coefficients = np.zeros((dim, order + 1, n_lanes))  # zero where heyoka's grid gives them
    start = np.empty(n_lanes)
    initial = np.empty((n_lanes, dim))
    stopped = np.zeros(n_lanes, bool)
    unmoved = np.zeros(n_lanes, bool)  # lanes whose grid is their start alone: no step
    by_grid = {}
    hits = misses = 0
    for b in range(n_lanes // width):
        lanes = slice(b * width, (b + 1) * width)
        prepare(b)
        start[lanes] = ta.time
        initial[lanes] = ta.state.T
        # one step at most: a batch that needs more wastes one step, not its whole arcs;
        # when most batches need more, the rest go to heyoka's grid directly
        if misses <= 2 * hits + 1:
            ta.propagate_until(np.ascontiguousarray(grid[lanes, -1]), max_steps=1, write_tc=True)
            kinds, _, _, steps = zip(*ta.propagate_res, strict=True)
            if kinds.count(_TIME_LIMIT) == width:
                coefficients[..., lanes] = ta.tc
                if min(steps) == 0:
                    unmoved[lanes] = np.asarray(steps) == 0
                hits += 1
                continue
            misses += 1
            prepare(b)
        # several steps, or a failure: heyoka's dense output over all of them
        by_grid[b], stopped[lanes] = _propagate_grid(
            ta, np.ascontiguousarray(grid[lanes].T), max_steps
        )
    delta = grid - start[:, None]
    powers = np.empty((n_lanes, m, order + 1))
    powers[..., 0] = 1.0
    powers[..., 1] = delta
    for k in range(2, order + 1):
        np.multiply(powers[..., k - 1], delta, out=powers[..., k])
    out = np.matmul(powers, coefficients.transpose(2, 1, 0))  # (lanes, m, n_state)
    for b, states in by_grid.items():
        out[b * width : (b + 1) * width] = states.transpose(2, 0, 1)
    out[unmoved] = initial[unmoved][:, None]
    out[stopped] = np.nan
    return out, stopped


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
            grid_states, stopped = _propagate_grid(  # (m, n_state, width)
                ta, np.ascontiguousarray(times[pad].T), max_steps
            )
            if stopped:
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
#: SIMD batches of arcs whose costate passes one thread runs and whose samples, nodes and
#: parameter rates it then handles together: numpy's cost is per call, not per arc, and it
#: holds the GIL, which a second thread's integrators do not need. On the bench's 112 arcs
#: (28 batches of 4) 14 took 0.8 of the time 4 took on two threads.
_BLOCK_BATCHES = 14
#: Parameter rates (floats: runtime parameters x nodes) held per block; a block has fewer
#: batches when its nodes would need more (32 MB).
_BLOCK_RATE_FLOATS = 4_000_000


@functools.lru_cache(maxsize=4)
def _lagrange_in_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(the n Gauss-Legendre nodes u_i on [-1, 1], B (n, n)): the Lagrange polynomial of node
    i is L_i(u) = sum_k B[i, k] P_k(u) (the quadrature integrates P_k P_l exactly for
    k + l <= 2n - 1, so the interpolant at its nodes has these Legendre coefficients)."""
    nodes, weights = np.polynomial.legendre.leggauss(n)
    legendre = np.polynomial.legendre.legvander(nodes, n - 1)  # P_k(u_i)
    basis = weights[:, None] * (2 * np.arange(n) + 1) / 2 * legendre
    nodes.setflags(write=False)  # cached: shared by every call
    basis.setflags(write=False)
    return nodes, basis


def _legendre_integrals(u: np.ndarray, n: int) -> np.ndarray:
    """F_k(u) = integral of P_k from -1 to u, k < n, shape (n, *u.shape)."""
    p = np.empty((n + 1, *np.shape(u)))  # P_k(u) by Bonnet's recursion
    p[0], p[1] = 1.0, u
    for k in range(1, n):
        p[k + 1] = ((2 * k + 1) * u * p[k] - k * p[k - 1]) / (k + 1)
    out = np.empty((n, *np.shape(u)))
    out[0] = u + 1.0
    for k in range(1, n):
        out[k] = (p[k + 1] - p[k - 1]) / (2 * k + 1)
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
    times: np.ndarray, states: np.ndarray | None, segments: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nodes of each arc (samples at ``times`` (n, m), m >= 2; ``states`` (n, m, 6), read
    only for the default ``segments``) for
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

    Returns (node times (n, K), weights (n, K, m - 1): d = weights @ c, each arc's node count
    k (n,)), K the largest k: an arc's nodes are its first k, the rest NaN with weight 0."""
    n_nodes = ADJOINT_SEGMENT_NODES
    unit_nodes, basis = _lagrange_in_legendre(n_nodes)
    start, span = times[:, 0], times[:, -1] - times[:, 0]
    if segments is None:
        segments = _segment_counts(times, states)
    counts = segments * n_nodes
    n, n_m = times.shape
    # every arc cut into as many segments as the most any needs; an arc's segments beyond its
    # own count get no nodes (NaN) and no weight
    width = span / segments  # (n,)
    index = np.arange(segments.max())
    left = start[:, None] + width[:, None] * index  # (n, S)
    # the samples in each segment's variable u in [-1, 1], clipped to the segment
    u = 2.0 * (times[:, None, :] - left[..., None]) / width[:, None, None] - 1.0
    integrals = _legendre_integrals(np.clip(u, -1.0, 1.0), n_nodes)  # (n_nodes, n, S, m)
    within = np.diff(integrals, axis=3)  # each interval's part
    own = index < segments[:, None]  # (n, S)
    weights = (
        np.einsum("ij,jnsk->nsik", basis, within)
        * np.where(own, 0.5 * width[:, None], 0.0)[..., None, None]
    )
    node_times = left[..., None] + 0.5 * width[:, None, None] * (unit_nodes + 1.0)
    node_times[~own] = np.nan
    weights = weights.reshape(n, -1, n_m - 1)
    node_times = node_times.reshape(n, -1)
    return node_times, weights, counts


def _block_grid(times: np.ndarray, node_times: np.ndarray, counts: np.ndarray) -> tuple:
    """The grid of a block's lanes (``times`` (w, m) and their :func:`_arc_nodes` node times
    (w, K) and counts (w,)): every lane's samples and nodes in time order, a lane's missing
    nodes (NaN) placed evenly inside the widest gap between its samples and nodes, apart
    from all (heyoka's grid is strictly increasing), so that all lanes share one grid length.
    Returns (grid (w, m + K), the samples' and the nodes' places in the grid (w, m),
    (w, K))."""
    m, k = times.shape[1], node_times.shape[1]
    missing = np.isnan(node_times)
    # with the missing nodes at the last sample, the widest gap is between real points
    points = np.sort(np.concatenate([times, np.where(missing, times[:, -1:], node_times)], 1), 1)
    gap = np.argmax(np.diff(points, axis=1), axis=1)[:, None]
    low = np.take_along_axis(points, gap, axis=1)
    high = np.take_along_axis(points, gap + 1, axis=1)
    fraction = (np.arange(k) - counts[:, None] + 1) / (k - counts[:, None] + 1)
    nodes = np.where(missing, low + (high - low) * fraction, node_times)
    # a sample sorts before a node at the same time (stable)
    joined = np.concatenate([times, nodes], axis=1)
    order = np.argsort(joined, axis=1, kind="stable")
    place = np.argsort(order, axis=1)
    return np.take_along_axis(joined, order, axis=1), place[:, :m], place[:, m:]


#: Layouts of recent blocks (:func:`_block_layout`), oldest first, and their size in floats.
_LAYOUTS: OrderedDict[bytes, tuple] = OrderedDict()
_LAYOUTS_KEPT = {"floats": 0}
#: Floats of block layouts kept between calls (64 MB).
_LAYOUT_FLOATS = 8_000_000
_LAYOUTS_LOCK = threading.Lock()


def _forget_layouts() -> None:
    """Drop the kept block layouts."""
    with _LAYOUTS_LOCK:
        _LAYOUTS.clear()
        _LAYOUTS_KEPT["floats"] = 0


def _block_layout(times: np.ndarray, segments: np.ndarray) -> tuple:
    """The nodes of a block's arcs (:func:`_arc_nodes`: node times, weights, counts) and its
    grid (:func:`_block_grid`: grid, the samples' and the nodes' places), for its lanes'
    sample times ``times`` (w, m), the first ``len(segments)`` of them its arcs (cut into
    ``segments`` segments) and the rest repeats of its last arc. The layout depends on these
    alone, not on the parameters: a fit asks for the gradient of the same arcs at every
    step, so recent layouts are kept (read only), up to :data:`_LAYOUT_FLOATS` floats."""
    n_arcs = len(segments)
    key = hashlib.blake2b(
        np.asarray([*times.shape, n_arcs, ADJOINT_SEGMENT_NODES]).tobytes()
        + np.asarray(ADJOINT_SEGMENT_PHASE).tobytes()
        + times.tobytes()
        + np.asarray(segments, dtype=np.int64).tobytes(),
        digest_size=16,
    ).digest()
    with _LAYOUTS_LOCK:
        if key in _LAYOUTS:
            _LAYOUTS.move_to_end(key)
            return _LAYOUTS[key]
    node_times, weights, counts = _arc_nodes(times[:n_arcs], None, np.asarray(segments))
    pad = len(times) - n_arcs
    grid, at_sample, at_node = _block_grid(
        times,
        np.concatenate([node_times, np.repeat(node_times[-1:], pad, axis=0)]),
        np.concatenate([counts, np.repeat(counts[-1:], pad)]),
    )
    layout = (node_times, weights, counts, grid, at_sample, at_node)
    for part in layout:
        part.setflags(write=False)
    size = sum(part.size for part in layout)
    with _LAYOUTS_LOCK:
        _LAYOUTS[key] = layout
        _LAYOUTS_KEPT["floats"] += size
        while _LAYOUTS_KEPT["floats"] > _LAYOUT_FLOATS and len(_LAYOUTS) > 1:
            _LAYOUTS_KEPT["floats"] -= sum(part.size for part in _LAYOUTS.popitem(last=False)[1])
    return layout


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
    node, a few per radian of motion, not per interval between samples. When the learnable
    term holds all the runtime parameters and reduces its rates itself
    (:meth:`hamgrav.core.terms.GravityTerm.parameter_rate_sum`: a network, by matrix
    products over all of a block's nodes), that sum replaces the node-by-node rates (which
    remain for a block whose sum is not finite, to find the arcs at fault). The costate
    pass's points come from its Taylor steps' coefficients (:func:`_propagate_lanes`).
    The arcs go in blocks of up to :data:`_BLOCK_BATCHES` SIMD batches, each handled whole by
    one thread (the threads take the next block as they finish). Memory: the states, and
    per thread one block's 42 variables at the samples and nodes and their rates
    (n_system_params per node, at most :data:`_BLOCK_RATE_FLOATS` unless one batch needs
    more), and the blocks' layouts kept between calls (:func:`_block_layout`, at most
    :data:`_LAYOUT_FLOATS` floats in all); never a sensitivity per sample. The first
    ``n_shared`` runtime parameters are shared by all arcs (their gradients summed); the rest
    are per arc (returned in ``per_arc``)."""
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
    # each block's sum of the shared gradient, added up in block order at the end: the
    # threads finish in any order, and a sum must not depend on it
    partial: dict[int, np.ndarray] = {}
    lock = threading.Lock()
    rates = parameter_rate_function(model)
    n_rate_pars = rates.nparams  # a cfunc counts parameters up to the last one it uses
    adjoint_tol = ADJOINT_TOLERANCE if adjoint_tol is None else adjoint_tol
    compiled = compiled_integrators(model, variational=True, wrt="state", tol=adjoint_tol)
    width = compiled.integrators[0].batch_size
    pending = np.flatnonzero(forward.ok)
    segments = np.zeros(n, int)
    if n_m > 1 and len(pending):
        segments[pending] = _segment_counts(times[pending], forward.states[pending])

    shared_rate_pars: dict[int, np.ndarray] = {}
    # with only shared parameters, all the learnable term's, the term may reduce its rates
    # over a block's nodes itself (GravityTerm.parameter_rate_sum; None: heyoka's rates)
    reduced_rates = None
    if model.learnable is not None and n_par == n_shared == model.learnable.n_params:
        reduced_rates = model.learnable.parameter_rate_sum
    shared_params = runtime_params[:n_shared, 0] if n else np.zeros(n_shared)
    identity = np.eye(6).reshape(36, 1)

    def rate_pars(sel: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """The rates' parameters at the nodes of the arcs ``sel`` (``counts`` each); when
        they are all shared, one array per node count, for every block (read only)."""
        if n_rate_pars > n_shared:
            return np.repeat(runtime_params[:n_rate_pars, sel], counts, axis=1)
        total = int(counts.sum())
        if total not in shared_rate_pars:  # two threads may both form it: the same array
            shared_rate_pars[total] = np.repeat(runtime_params[:n_rate_pars, sel[:1]], total, 1)
        return shared_rate_pars[total]

    def block_gradient(ta, sel: np.ndarray):
        """The arcs ``sel``: the sum of their gradients' shared part over those that ended
        well (n_shared,), each one's per-arc part (n_par - n_shared, len(sel)), whether each
        ended well, and whether the step limit stopped it."""
        n_sel, n_batches = len(sel), -(-len(sel) // width)
        lanes = np.concatenate([sel, np.repeat(sel[-1:], n_batches * width - n_sel)])
        node_times, node_weights, counts, grid, at_sample, at_node = _block_layout(
            times[lanes], segments[sel]
        )
        starts = times[lanes, 0].reshape(n_batches, width)
        firsts = np.ascontiguousarray(
            states0[lanes].reshape(n_batches, width, 6).transpose(0, 2, 1)
        )
        pars = ta.pars
        pars[:n_shared] = runtime_params[:n_shared, sel[:1]]  # the same for every arc
        own_pars = runtime_params[n_shared:, lanes]
        st = ta.state

        def prepare(b: int) -> None:
            ta.set_time(starts[b])
            st[:6] = firsts[b]
            st[6:] = identity
            if own_pars.size:
                pars[n_shared:] = own_pars[:, b * width : (b + 1) * width]

        out, stopped = _propagate_lanes(ta, grid, prepare, max_steps)  # (lanes, grid, 42)
        # each arc's states and transition matrices at its samples and its nodes, from its lane
        n_nodes = node_times.shape[1]
        arc = np.arange(n_sel)[:, None]
        samples = out[arc, at_sample[:n_sel]]  # (arcs, samples, 42)
        at_nodes = out[arc, at_node[:n_sel]]  # (arcs, nodes, 42)
        phi_samples = samples[..., 6:].reshape(n_sel, n_m, 6, 6)
        phi_nodes = at_nodes[..., 6:].reshape(n_sel, n_nodes, 6, 6)
        jumps = np.einsum("lkij,lki->lkj", phi_samples, kicks[sel])  # Phi_k^T dJ/dx_k
        after = np.cumsum(jumps[:, ::-1], axis=1)[:, ::-1][:, 1:]  # sum over j > k
        # each node's share of the costate (see _arc_nodes): d_i = sum_k W_ik c_k
        c = np.matmul(node_weights, after)  # (arcs, nodes, 6)
        # Phi is symplectic (Hamilton's equations in canonical (q, p)): Phi^-T = -J Phi J,
        # so lam = Phi^-T d is (-v_p, v_q) for v = Phi (d_p, -d_q), with no solve
        v = np.einsum("lnij,lnj->lni", phi_nodes, np.concatenate([c[..., 3:], -c[..., :3]], -1))
        lam = np.concatenate([-v[..., 3:], v[..., :3]], axis=-1)
        # the rates at each arc's own nodes only (not at a lane's padding)
        real = np.arange(n_nodes) < counts[:, None]
        good = np.all(np.isfinite(lam), axis=(1, 2)) & ~stopped[:n_sel]
        if reduced_rates is not None and good.all():
            # the learnable term's rates summed over all the block's nodes at once
            shared = reduced_rates(shared_params, at_nodes[..., :3][real], lam[..., 3:][real])
            if shared is not None and np.all(np.isfinite(shared)):
                return shared, np.zeros((0, n_sel)), good, stopped[:n_sel]
        points = np.concatenate([at_nodes[..., :6], lam], axis=-1)[real]
        extra = {"time": node_times[real]} if rates.is_time_dependent else {}
        if n_rate_pars:
            extra["pars"] = rate_pars(sel, counts)
        values = rates(np.ascontiguousarray(points.T), batch_parallel=False, **extra)
        # the shared part summed over the block's nodes at once; arc by arc only for the
        # per-arc parameters, or to find the arcs whose rates are not finite
        shared = -values[:n_shared].sum(axis=1)
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        per_arc = -np.add.reduceat(values[n_shared:], first, axis=1)
        if not (np.all(np.isfinite(shared)) and np.all(np.isfinite(per_arc)) and good.all()):
            sums = -np.add.reduceat(values, first, axis=1)
            good &= np.all(np.isfinite(sums), axis=0)
            shared = sums[:n_shared, good].sum(axis=1)
        return shared, per_arc, good, stopped[:n_sel]

    if len(pending) and n_m > 1:
        rate_floats = n_par * width * int(segments.max()) * ADJOINT_SEGMENT_NODES  # a batch's
        arcs_per_block = width * int(np.clip(_BLOCK_RATE_FLOATS // rate_floats, 1, _BLOCK_BATCHES))
        # each block takes every n_blocks-th batch of neighbouring arcs: arcs come in orbit
        # order, and a block of low, many-step orbits alone would leave a thread idle
        batches = [pending[i : i + width] for i in range(0, len(pending), width)]
        n_blocks = -(-len(pending) // arcs_per_block)
        blocks = [np.concatenate(batches[j::n_blocks]) for j in range(n_blocks)]
        n_threads = max(1, min(int(threads or os.cpu_count() or 1), len(blocks)))
        queue = iter(range(len(blocks)))

        def work(ta, worker):
            while True:
                with lock:  # the next block not yet taken: threads share out uneven blocks
                    key = next(queue, None)
                if key is None:
                    return
                sel = blocks[key]
                shared, own, good, stopped = block_gradient(ta, sel)
                with lock:
                    ok[sel] &= good
                    exceeded[sel] |= stopped
                    per_arc[sel] = own.T
                    partial[key] = shared

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
    time. One compiled scalar integrator (the state transition equations of
    :func:`hamgrav.core.hamiltonian.transition_equations`), from the compile cache like the
    others."""
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
            res = ta.propagate_grid(times, max_steps=max_steps_per_chunk)
            states = res[-1]
            n_ok = len(states)
            if res[0] == hy.taylor_outcome.step_limit:
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

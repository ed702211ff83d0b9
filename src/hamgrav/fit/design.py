"""D-optimal choice of the next orbits to track, from the current model (no measurements).

For a candidate orbit c, its arcs are *predicted*: the candidate is started circular as in
:func:`hamgrav.sim.tracking.simulate_orbits` and propagated under the current model at theta_k
(never the truth), and the arcs are cut from the window exactly as there. Its information
matrix is

    Lambda_c = sum over the predicted samples of Phi^T Phi = A^T A,

with Phi = d state / d theta of each arc anchored at its first sample (A = -Phi is the design
matrix of :class:`hamgrav.core.problem.ArcProblem`; with a whitening W, the whitened
A = -W Phi). The D-optimal score of c given the information accumulated so far, L_acc, is

    Delta(c) = logdet(L_acc + Lambda_c + eps I) - logdet(L_acc + eps I),
    eps = max(1e-8, 1e-6 tr(L_acc) / n_p),

and the greedy design picks the argmax from a pool, adds its Lambda to L_acc and repeats.
Log-determinants are taken by Cholesky factorisation.

A candidate can also be an :class:`OrbitPlan`, an orbit already laid out (initial state and
sample times, e.g. those of a campaign's simulated orbits, :func:`orbit_plans`), predicted
the same way (:func:`predicted_plan_arcs`); :func:`choose_from_plans` is the greedy choice
among plans given the information accumulated so far. A network ensemble, whose members are
fitted each on its own, has block-diagonal information: one block per member, eps per block.

Everything is in canonical units (mu = omega = 1): times in spin periods / 2 pi, lengths in the
synchronous radius, Lambda in (canonical state units / parameter units)^2.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from functools import partial

import numpy as np
from scipy.linalg import cho_factor

from ..core.arcs import Arcs
from ..core.mascons import MasconSet
from ..core.model import DEFAULT_FIT_TOLERANCE, Model
from ..core.problem import ArcProblem
from ..core.propagation import propagate_batch
from ..errors import InputError
from ..sim.tracking import OrbitFamily, TrackingConfig, arc_start_times, draw_orbit_start
from ..units import CanonicalUnits
from .continual import ContinualFit
from .estimator import GravityEstimator

__all__ = [
    "d_optimal_campaign",
    "OrbitPlan",
    "orbit_plans",
    "predicted_arcs",
    "predicted_plan_arcs",
    "information_matrix",
    "trajectory_informations",
    "regularisation",
    "logdet_regularised",
    "d_optimal_gain",
    "greedy_d_optimal",
    "random_order_logdet",
    "choose_from_plans",
    "select_orbits",
]


# ---------------------------------------------------------------------------- predicted arcs
def _draw_candidates(rng, families, tracking, window, arc_offsets, r_b):
    """Per family, in the random-number order of ``simulate_orbits`` (arc starts, then node
    and argument of latitude of its first draw): sample times (k, m) and the initial state."""
    out = []
    for family in families:
        starts = arc_start_times(rng, tracking.arcs_per_orbit, window, arc_offsets[-1])
        raan, arg_lat, state0 = draw_orbit_start(rng, family, r_b)
        out.append((starts[:, None] + arc_offsets[None, :], raan, arg_lat, state0))
    return out


@dataclass(frozen=True, eq=False)
class OrbitPlan:
    """An orbit as planned before it is flown: its ``family`` (start radius [R_B],
    inclination [deg]), its canonical initial state (6,) at t = 0 and the canonical sample
    times (n_arcs, m) of its arcs. A plan holds no measurement and nothing of the truth."""

    family: OrbitFamily
    initial_state: np.ndarray
    times: np.ndarray


def orbit_plans(arcs: Arcs) -> list[OrbitPlan]:
    """The plans of the orbits of simulated ``arcs`` (one per trajectory, in trajectory
    order): the start radius, inclination and initial state recorded by
    :func:`~hamgrav.sim.tracking.simulate_orbits` and the arcs' sample times; the measured
    and true states are not read."""
    info = arcs.trajectory_info
    return [
        OrbitPlan(
            OrbitFamily(float(info["radius_rb"][k]), float(info["inclination_deg"][k])),
            np.asarray(info["initial_state"][k], dtype=float),
            np.asarray(arcs.times[arcs.trajectory == k], dtype=float),
        )
        for k in range(arcs.n_trajectories)
    ]


def predicted_arcs(
    model: Model,
    theta,
    families: list[OrbitFamily],
    tracking: TrackingConfig,
    *,
    brillouin_radius: float,
    body_name: str,
    gm_m3_s2: float,
    spin_period_s: float,
    seed: int = 0,
    trajectory_values=None,
    tol: float = DEFAULT_FIT_TOLERANCE,
) -> Arcs:
    """Noiseless arcs of one candidate orbit per family, predicted under ``model`` at ``theta``.

    Each candidate starts circular at ``radius_rb * brillouin_radius`` (canonical) with a
    seeded node and argument of latitude, and its arcs are placed in the window as in
    :func:`~hamgrav.tracking.simulate_orbits` (same random-number order: with the same seed
    and families, the initial states and sample times equal those of a simulation whose
    orbits needed no redraw). There is no shape here, so there are no redraws: a candidate
    whose prediction diverges (non-finite) or escapes (r > ``tracking.escape_factor`` times
    its initial radius at a sample) is dropped; its family index is listed in
    ``trajectory_info["dropped"]`` and ``trajectory_info["candidate"]`` maps each kept
    trajectory to its family index.

    Args:
        model: the current model; ``theta[:model.n_learn]`` are its learnable parameters.
        families: candidate orbit families (radius [R_B], inclination [deg]).
        tracking: arcs per orbit, samples per arc, cadence [s], window [spin periods].
        brillouin_radius: canonical Brillouin radius of the body.
        body_name, gm_m3_s2 [m^3/s^2], spin_period_s [s]: the body and its canonical units.
        seed: seed of the arc placement and of the nodes / arguments of latitude.
        trajectory_values: values of the model's per-trajectory parameters used for every
            candidate (default zeros: e.g. SRP switched off in the prediction).
        tol: integrator tolerance.

    Returns:
        An :class:`Arcs` with the predictions in both ``states`` and ``true_states``, zero
        noise levels, a placeholder ``truth`` and interior ``"predicted"``.
    """
    if not families:
        raise InputError("the candidate pool needs at least one orbit family")
    units = CanonicalUnits(gm_m3_s2, spin_period_s)
    rng = np.random.default_rng(seed)
    arc_offsets = float(units.to_time(tracking.cadence_s)) * np.arange(tracking.samples_per_arc)
    window = 2.0 * math.pi * tracking.window_spin_periods
    draws = _draw_candidates(rng, families, tracking, window, arc_offsets, brillouin_radius)
    plans = [OrbitPlan(f, d[3], d[0]) for f, d in zip(families, draws, strict=True)]
    arcs = predicted_plan_arcs(
        model,
        theta,
        plans,
        brillouin_radius=brillouin_radius,
        body_name=body_name,
        gm_m3_s2=gm_m3_s2,
        spin_period_s=spin_period_s,
        escape_factor=tracking.escape_factor,
        trajectory_values=trajectory_values,
        tol=tol,
    )
    kept = arcs.trajectory_info["candidate"]
    arcs.trajectory_info["raan_deg"] = np.array([math.degrees(draws[k][1]) for k in kept])
    arcs.trajectory_info["arg_lat_deg"] = np.array([math.degrees(draws[k][2]) for k in kept])
    arcs.config["seed"] = seed
    arcs.config["tracking"] = asdict(tracking)
    return replace(arcs, seed=seed)


def predicted_plan_arcs(
    model: Model,
    theta,
    plans: list[OrbitPlan],
    *,
    brillouin_radius: float,
    body_name: str,
    gm_m3_s2: float,
    spin_period_s: float,
    escape_factor: float = 3.0,
    trajectory_values=None,
    tol: float = DEFAULT_FIT_TOLERANCE,
) -> Arcs:
    """Noiseless arcs of planned orbits (:class:`OrbitPlan`, all with the same arcs and
    samples per arc), predicted under ``model`` at ``theta`` from their initial states:
    the one prediction path of :func:`predicted_arcs`. A plan whose prediction diverges or
    escapes (r > ``escape_factor`` times its initial radius at a sample) is dropped:
    ``trajectory_info["candidate"]`` maps each kept trajectory to its plan index and
    ``trajectory_info["dropped"]`` lists the dropped plans. Canonical units throughout;
    ``brillouin_radius`` (canonical) scales ``min_radius_rb``; the body's name, GM
    [m^3/s^2] and spin period [s] label the arcs."""
    if not plans:
        raise InputError("the candidate pool needs at least one orbit")
    theta = np.asarray(theta, dtype=float)
    if trajectory_values is None:
        trajectory_values = np.zeros(model.n_trajectory_params)
    if theta.size < model.n_learn:
        raise ValueError(f"theta must have at least {model.n_learn} entries, got {theta.size}")
    shapes = {np.shape(p.times) for p in plans}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise InputError("every planned orbit needs the same (arcs, samples) sample times")
    n_cand = len(plans)
    n_arc, n_m = next(iter(shapes))
    pars = np.zeros((model.n_system_params, n_cand))
    pars[: model.n_learn] = theta[: model.n_learn, None]
    if model.n_trajectory_params:
        pars[model.n_learn :] = np.asarray(trajectory_values, dtype=float).reshape(-1, 1)
    # each grid starts at the plan's start time, 0: drop that column afterwards
    grids = np.stack([np.concatenate([[0.0], np.ravel(p.times)]) for p in plans])
    states0 = np.stack([np.asarray(p.initial_state, dtype=float) for p in plans])
    run = propagate_batch(model, states0, grids, pars, tol=tol)
    predicted = run.states[:, 1:]  # NaN where the prediction failed

    radius0 = np.linalg.norm(states0[:, :3], axis=1)
    r = np.linalg.norm(predicted[..., :3], axis=-1)
    finite = np.all(np.isfinite(predicted), axis=(1, 2))
    keep = finite & np.all(
        np.where(finite[:, None], r, 0.0) <= escape_factor * radius0[:, None], axis=1
    )
    kept = np.flatnonzero(keep)

    info = {
        "radius_rb": np.array([plans[k].family.radius_rb for k in kept]),
        "inclination_deg": np.array([plans[k].family.inclination_deg for k in kept]),
        "initial_state": states0[kept].reshape(-1, 6),
        "min_radius_rb": r[kept].min(axis=1) / brillouin_radius,
        "candidate": kept,
        "dropped": np.flatnonzero(~keep),  # plan indices (not one entry per trajectory)
    }
    states = predicted[kept].reshape(-1, n_m, 6)
    return Arcs(
        times=np.array([plans[k].times for k in kept]).reshape(-1, n_m),
        states=states,
        true_states=states.copy(),
        trajectory=np.repeat(np.arange(len(kept), dtype=np.int64), n_arc),
        trajectory_kind=tuple("orbit" for _ in kept),
        trajectory_info=info,
        body_name=body_name,
        gm_m3_s2=gm_m3_s2,
        spin_period_s=spin_period_s,
        body_origin_m=(0.0, 0.0, 0.0),
        sigma_r_m=0.0,
        sigma_v_m_s=0.0,
        truth=MasconSet(np.zeros((1, 3)), np.ones(1)),
        interior="predicted",
        interior_parameters={},
        config={"design": "predicted", "model": model.describe()},
    )


# ---------------------------------------------------------------------------- information
def _problem(problem_or_model, arcs) -> ArcProblem:
    if isinstance(problem_or_model, ArcProblem):
        if arcs is not None and arcs is not problem_or_model.arcs:
            raise ValueError(
                "give either an ArcProblem or a model with arcs, not a problem with other arcs"
            )
        return problem_or_model
    if arcs is None:
        raise InputError("a model needs arcs")
    return ArcProblem(problem_or_model, arcs)


def information_matrix(problem_or_model, theta, arcs: Arcs | None = None, arc_indices=None):
    """Lambda = A^T A (n_p, n_p) of the (selected) arcs at ``theta``: the sum over samples of
    Phi^T Phi. Give an :class:`ArcProblem` (its arcs, whitening and SRP settings are used) or a
    :class:`Model` and ``arcs``. The arcs' states only anchor the propagations."""
    problem = _problem(problem_or_model, arcs)
    theta = np.asarray(theta, dtype=float)
    return problem.normal_equations(theta, arc_indices, regularised=False)[2]


def _information_of(problem: ArcProblem, theta, arc_indices) -> np.ndarray:
    return information_matrix(problem, theta, arc_indices=arc_indices)


def trajectory_informations(problem_or_model, theta, arcs: Arcs | None = None, *, mapper=map):
    """One information matrix per trajectory (orbit) of the arcs, in trajectory order.

    Each is an independent work unit of plain data; ``mapper`` (builtin ``map`` by default, or
    a Dask client's) runs them."""
    problem = _problem(problem_or_model, arcs)
    traj = problem.arcs.trajectory
    groups = [np.flatnonzero(traj == k) for k in range(problem.arcs.n_trajectories)]
    theta = np.asarray(theta, dtype=float)
    return list(mapper(partial(_information_of, problem, theta), groups))


# ---------------------------------------------------------------------------- D-optimality
def regularisation(L_acc) -> float:
    """eps = max(1e-8, 1e-6 tr(L_acc) / n_p)."""
    L_acc = np.asarray(L_acc, dtype=float)
    return max(1e-8, 1e-6 * float(np.trace(L_acc)) / L_acc.shape[0])


def _logdet(m: np.ndarray) -> float:
    c, _ = cho_factor(m, lower=True)
    return 2.0 * float(np.sum(np.log(np.diag(c))))


def logdet_regularised(L) -> float:
    """logdet(L + eps(L) I), by Cholesky."""
    L = np.asarray(L, dtype=float)
    return _logdet(L + regularisation(L) * np.eye(L.shape[0]))


def d_optimal_gain(L_acc, L_c) -> float:
    """Delta = logdet(L_acc + L_c + eps I) - logdet(L_acc + eps I), eps from L_acc."""
    L_acc = np.asarray(L_acc, dtype=float)
    reg = regularisation(L_acc) * np.eye(L_acc.shape[0])
    return _logdet(L_acc + np.asarray(L_c, dtype=float) + reg) - _logdet(L_acc + reg)


def _blocks(matrix) -> tuple[np.ndarray, ...]:
    """An information matrix as its diagonal blocks: a tuple of blocks as given, else the
    matrix as one block."""
    if isinstance(matrix, tuple | list):
        return tuple(np.asarray(b, dtype=float) for b in matrix)
    return (np.asarray(matrix, dtype=float),)


def _logdet_blocks(blocks, regs) -> float:
    """sum over blocks of logdet(block + reg I)."""
    return sum(_logdet(b + r * np.eye(b.shape[0])) for b, r in zip(blocks, regs, strict=True))


def _start(infos, n_pick, L_start):
    if not infos:
        raise ValueError("the candidate pool is empty")
    if not 0 <= n_pick <= len(infos):
        raise ValueError(f"cannot pick {n_pick} of {len(infos)} candidates")
    if L_start is not None:
        return _blocks(L_start)
    return tuple(np.zeros_like(b) for b in _blocks(infos[0]))


def greedy_d_optimal(infos, n_pick: int, L_start=None):
    """Greedy D-optimal picks (without replacement) from candidate information matrices.

    A candidate's information may be a tuple of diagonal blocks (e.g. one per independently
    fitted network of an ensemble): its log det is then the sum of the blocks' and eps is
    taken per block, each block treated as the information matrix of its own parameters.

    Returns ``(picked, logdets, gains)``: the candidate indices in pick order, logdet(L_acc +
    eps(L_acc) I) after each pick, and the gain Delta of each pick when it was made.
    """
    L_acc = _start(infos, n_pick, L_start)
    blocks = [_blocks(i) for i in infos]
    left = list(range(len(infos)))
    picked, logdets, gains = [], [], []
    for _ in range(n_pick):
        # eps and logdet(L_acc + eps I) are shared by every candidate of this pick
        regs = [regularisation(b) for b in L_acc]
        base = _logdet_blocks(L_acc, regs)
        scores = [
            _logdet_blocks([a + c for a, c in zip(L_acc, blocks[k], strict=True)], regs) - base
            for k in left
        ]
        best = left.pop(int(np.argmax(scores)))
        gains.append(float(max(scores)))
        picked.append(best)
        L_acc = tuple(a + c for a, c in zip(L_acc, blocks[best], strict=True))
        logdets.append(_logdet_blocks(L_acc, [regularisation(b) for b in L_acc]))
    return picked, np.asarray(logdets), np.asarray(gains)


def random_order_logdet(infos, n_pick: int, seed: int = 0, L_start=None):
    """``(picked, logdets)`` for a seeded random pick order, logdets as in the greedy."""
    L_acc = _start(infos, n_pick, L_start)
    picked = [int(k) for k in np.random.default_rng(seed).permutation(len(infos))[:n_pick]]
    logdets = []
    for k in picked:
        L_acc = tuple(a + c for a, c in zip(L_acc, _blocks(infos[k]), strict=True))
        logdets.append(_logdet_blocks(L_acc, [regularisation(b) for b in L_acc]))
    return picked, np.asarray(logdets)


def choose_from_plans(
    model: Model,
    theta,
    plans: list[OrbitPlan],
    *,
    pool,
    picks: int,
    brillouin_radius: float,
    body_name: str,
    gm_m3_s2: float,
    spin_period_s: float,
    L_acc=None,
    escape_factor: float = 3.0,
    tol: float = DEFAULT_FIT_TOLERANCE,
    mapper=map,
) -> dict:
    """Greedy D-optimal choice of ``picks`` orbits from ``pool`` (indices into ``plans``):
    each pool plan is predicted under ``model`` at ``theta`` (:func:`predicted_plan_arcs`),
    its information matrix built from the predicted sensitivities, and the greedy picks
    maximise Delta given ``L_acc`` (:func:`greedy_d_optimal`, eps of the paper), the
    information accumulated by the orbits already selected (None: zero, as at the first
    selection). No measurement and no truth enter: the result depends on the plans, the
    model, ``theta`` and ``L_acc`` only. For a network ensemble, whose members are fitted each
    on its own (:class:`~hamgrav.fit.estimator.GravityEstimator`), the information is
    block-diagonal: one block per member, predicted under that member alone at its block of
    ``theta``, eps per block (the gain is the sum of the members' gains).

    Returns ``{"picked": plan indices in pick order, "gains": Delta of each pick, "logdets":
    log det(L_acc + eps I) after each pick, "dropped": pool plans whose prediction diverged or
    escaped (never picked), "L_acc": the accumulated information after the picks (blocks)}``.
    Canonical units; ``brillouin_radius`` canonical, the body's name, GM [m^3/s^2] and spin
    period [s] label the predicted arcs."""
    pool = [int(k) for k in pool]
    if len(set(pool)) != len(pool):
        raise InputError("the candidate pool lists an orbit twice")
    theta = np.asarray(theta, dtype=float)[: model.n_learn]
    term = model.learnable
    if term is not None and term.members > 1:
        # the members are fitted each on its own: one information block per member,
        # predicted under that member alone
        member = model.member()
        parts = [(member, block) for block in term.split_members(theta)]
    else:
        parts = [(model, theta)]
    per_part = []
    for part_model, part_theta in parts:
        arcs = predicted_plan_arcs(
            part_model,
            part_theta,
            [plans[k] for k in pool],
            brillouin_radius=brillouin_radius,
            body_name=body_name,
            gm_m3_s2=gm_m3_s2,
            spin_period_s=spin_period_s,
            escape_factor=escape_factor,
            tol=tol,
        )
        infos = trajectory_informations(part_model, part_theta, arcs, mapper=mapper)
        kept = [pool[int(c)] for c in arcs.trajectory_info["candidate"]]
        per_part.append(dict(zip(kept, infos, strict=True)))
    candidates = [k for k in pool if all(k in part for part in per_part)]
    dropped = [k for k in pool if k not in candidates]
    if not candidates:
        raise InputError("every candidate orbit diverged or escaped under the model")
    cand_infos = [tuple(part[k] for part in per_part) for k in candidates]
    n_pick = min(picks, len(candidates))
    start = L_acc if L_acc is not None else tuple(np.zeros_like(b) for b in cand_infos[0])
    chosen, logdets, gains = greedy_d_optimal(cand_infos, n_pick, L_start=start)
    total = _blocks(start)
    for c in chosen:
        total = tuple(a + b for a, b in zip(total, cand_infos[c], strict=True))
    return {
        "picked": [candidates[c] for c in chosen],
        "gains": [float(g) for g in gains],
        "logdets": [float(v) for v in logdets],
        "dropped": dropped,
        "L_acc": total,
    }


def select_orbits(
    fitted,
    families: list[OrbitFamily],
    tracking: TrackingConfig,
    *,
    brillouin_radius: float,
    picks: int,
    seed: int = 0,
    mapper=map,
) -> list[dict]:
    """Greedy D-optimal choice of ``picks`` orbits from candidate ``families`` at a fitted
    model (a :class:`~hamgrav.fit.fitted.FittedModel`): predicted arcs and sensitivities
    under the model, no measurements, no truth. One row per pick: candidate index, radius
    [R_B], inclination [deg], gain, log det after the pick, and log det of a seeded random
    order after as many picks."""
    candidates = predicted_arcs(
        fitted.model,
        fitted.params,
        list(families),
        tracking,
        brillouin_radius=brillouin_radius,
        body_name=fitted.body_name,
        gm_m3_s2=fitted.gm_m3_s2,
        spin_period_s=fitted.spin_period_s,
        seed=seed,
    )
    if candidates.n_trajectories == 0:
        raise InputError("every candidate orbit diverged or escaped under the model")
    infos = trajectory_informations(
        fitted.model, fitted.params[: fitted.model.n_learn], candidates, mapper=mapper
    )
    n_pick = min(picks, len(infos))
    chosen, logdets, gains = greedy_d_optimal(infos, n_pick)
    _, random_logdets = random_order_logdet(infos, n_pick, seed=seed)
    family_of = candidates.trajectory_info["candidate"]
    rows = []
    for k, (c, ld, g) in enumerate(zip(chosen, logdets, gains, strict=True)):
        fam = families[int(family_of[c])]
        rows.append(
            {
                "pick": k + 1,
                "candidate": int(family_of[c]),
                "radius_rb": fam.radius_rb,
                "inclination_deg": fam.inclination_deg,
                "gain": float(g),
                "logdet": float(ld),
                "random_order_logdet": float(random_logdets[k]),
            }
        )
    return rows


def d_optimal_campaign(
    estimator: GravityEstimator,
    arcs: Arcs,
    plans: list[OrbitPlan],
    sizes: list[int],
    *,
    brillouin_radius: float,
    escape_factor: float = 3.0,
    mapper=map,
) -> tuple[ContinualFit, list[dict]]:
    """The D-optimal campaign: before stage k, ``sizes[k]`` orbits are chosen from the plans
    not yet flown (:func:`hamgrav.fit.design.choose_from_plans`, under the estimator's current
    parameters: its seeded initialisation before the first stage, as the accumulated
    information starts at zero), then their arcs (orbit i of ``plans`` is trajectory i of
    ``arcs``) are added and the estimator refitted, warm after the first stage. As in the
    paper the accumulated information is the running sum of each pick's information as
    predicted when it was picked. Only the plans, the model, its parameters and that sum
    enter a choice.
    Returns the continual fit and each stage's choice (picked plan indices, gains, log dets,
    dropped plans). ``brillouin_radius`` is canonical."""
    model, _ = estimator.build_model(arcs)
    theta = estimator.initial_params(model, arcs)
    run = ContinualFit(estimator, arcs)
    flown: list[int] = []
    L_acc = None
    choices = []
    for size in sizes:
        pool = [i for i in range(len(plans)) if i not in flown]
        if not pool:
            break
        choice = choose_from_plans(
            model,
            theta,
            plans,
            pool=pool,
            picks=size,
            L_acc=L_acc,
            brillouin_radius=brillouin_radius,
            body_name=arcs.body_name,
            gm_m3_s2=arcs.gm_m3_s2,
            spin_period_s=arcs.spin_period_s,
            escape_factor=escape_factor,
            mapper=mapper,
        )
        L_acc = choice.pop("L_acc")
        flown += choice["picked"]
        theta = run.add(arcs.arcs_of(choice["picked"])).result.params
        choices.append(choice)
    return run, choices

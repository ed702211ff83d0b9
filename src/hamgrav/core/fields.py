"""Field-error metrics of the paper and the point sets they are evaluated on (canonical units).

eps = sqrt(sum (V_model - V_truth)^2 / sum (V_truth - 1/r)^2) over an evaluation set: the error
of the whole model (known part plus learnable term) relative to the perturbing potential, the
truth minus the central term. eps = 1 is the error of applying no correction at all (the point
mass alone); a shape prior alone scores how much of the perturbation the constant-density shape
misses, and a residual model on the prior is compared on the same scale as one without it.
"""

from __future__ import annotations

import numpy as np

from .mascons import MasconSet, mascon_acceleration, mascon_potential
from .model import Model, evaluate_field

__all__ = [
    "central_potential",
    "perturbing_potential",
    "shell_points",
    "relative_field_error",
    "perturbation_ratio",
    "model_perturbing_potential",
    "field_errors",
    "pointwise_field_errors",
    "member_spread",
]


def central_potential(points: np.ndarray) -> np.ndarray:
    """1/r of the unit point mass at the origin, at ``points`` (n, 3) [canonical length];
    returns (n,) [canonical potential]."""
    return 1.0 / np.linalg.norm(np.atleast_2d(points), axis=1)


def perturbing_potential(mascons: MasconSet, points: np.ndarray) -> np.ndarray:
    """V - 1/r of a unit-mass mascon set at ``points`` (n, 3) [canonical length]: what a
    correction term has to represent; returns (n,) [canonical potential]."""
    return mascon_potential(mascons, points) - central_potential(points)


#: Largest shell radius a field error is computed on [R_B]. The truth's perturbing potential
#: is its total potential minus 1/r, and falls as (R_B / r)^2 of 1/r or faster: at 1e3 R_B it
#: is about 1e-8 of 1/r and keeps some 8 digits of float64's 16, while by 1e8 R_B round-off
#: is all that is left (the error of an SH 2 fit reads 0.165 at 1e3 and 1e5 R_B, 1.01 at 1e8
#: and non-finite at 1e300: the truth there is noise, not the model's failing).
MAX_SHELL_RB = 1e3


def shell_points(radius: float, n: int = 500, seed: int = 0) -> np.ndarray:
    """``n`` seeded random directions (uniform on the sphere) at ``radius`` [canonical]; (n, 3)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    return radius * u / np.linalg.norm(u, axis=1, keepdims=True)


def relative_field_error(v_model: np.ndarray, v_truth: np.ndarray) -> float:
    """eps = sqrt(sum (V_model - V_truth)^2 / sum V_truth^2) (dimensionless).

    0 is a perfect recovery; 1 is the error of no correction at all (V_model = 0).
    """
    v_model = np.asarray(v_model, dtype=float)
    v_truth = np.asarray(v_truth, dtype=float)
    if v_model.shape != v_truth.shape:
        raise ValueError(f"shape mismatch: model {v_model.shape} vs truth {v_truth.shape}")
    return float(np.sqrt(np.sum((v_model - v_truth) ** 2) / np.sum(v_truth**2)))


def perturbation_ratio(mascons: MasconSet, points: np.ndarray) -> float:
    """Median over ``points`` of |a_perturbing| / |a_central| (dimensionless)."""
    points = np.atleast_2d(points)
    a_total = mascon_acceleration(mascons, points)
    r = np.linalg.norm(points, axis=1, keepdims=True)
    a_central = -points / r**3
    ratio = np.linalg.norm(a_total - a_central, axis=1) / np.linalg.norm(a_central, axis=1)
    return float(np.median(ratio))


def model_perturbing_potential(model: Model, params: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The whole ``model``'s potential at ``params`` (known part plus learnable term) minus the
    central term 1/r, at canonical ``points`` (n, 3); returns (n,) [canonical]: the model's
    counterpart of :func:`perturbing_potential`."""
    v_model, _ = evaluate_field(model, params, points, which="total")
    return v_model - central_potential(points)


def field_errors(
    model: Model, params: np.ndarray, truth: MasconSet, sets: dict[str, np.ndarray]
) -> dict[str, float]:
    """Relative field error of the whole ``model`` at ``params`` (known part plus learnable
    term) against the truth's perturbing potential, on each named point set (canonical points
    (n, 3)); see the module docstring. 1.0 for the point mass alone."""
    return {
        name: relative_field_error(
            model_perturbing_potential(model, params, pts), perturbing_potential(truth, pts)
        )
        for name, pts in sets.items()
    }


def acceleration_field_error(
    model: Model, params: np.ndarray, truth: MasconSet, points: np.ndarray
) -> float:
    """Relative error of the whole ``model``'s perturbing acceleration (the gradient of its
    perturbing potential) against the truth's at canonical ``points`` (n, 3):
    sqrt(sum |a_model - a_truth|^2 / sum |a_truth|^2), dimensionless (1 for the point mass
    alone). What tracking observes, where :func:`field_errors` scores the potential."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    central = -points / np.linalg.norm(points, axis=1, keepdims=True) ** 3
    _, a_model = evaluate_field(model, params, points, which="total")
    a_truth = mascon_acceleration(truth, points)
    return relative_field_error(a_model - central, a_truth - central)


def pointwise_field_errors(
    model: Model, params: np.ndarray, truth: MasconSet, points: np.ndarray
) -> np.ndarray:
    """|V_model - V_truth| / |V_truth| of the perturbing potentials at each of ``points``
    (n, 3), canonical; returns (n,), dimensionless: the one-point form of
    :func:`relative_field_error` (1 = no correction there). Where the truth's perturbing
    potential crosses zero the ratio grows without bound for every model."""
    target = perturbing_potential(truth, points)
    return np.abs(model_perturbing_potential(model, params, points) - target) / np.abs(target)


def member_spread(model: Model, params: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The standard deviation of an ensemble's members' learned potentials at ``points``
    (n, 3), divided by sqrt(members): how far the ensemble's mean would move with other
    initialisations (n,) [canonical potential]. Needs no truth; zeros for one network."""
    term = model.learnable
    points = np.atleast_2d(np.asarray(points, dtype=float))
    if term is None or term.members < 2:
        return np.zeros(len(points))
    member = model.member()
    values = [
        evaluate_field(member, block, points, which="learnable")[0]
        for block in term.split_members(np.asarray(params, dtype=float)[: model.n_learn])
    ]
    return np.std(values, axis=0, ddof=1) / np.sqrt(term.members)

"""Estimator facade: ``GravityEstimator(...).fit(arcs)`` in the scikit-learn style.

Hyperparameters are stored as given; ``fit`` builds the model (known part + learnable term),
the arc problem and the solver, runs it, and sets the learned attributes ``params_``,
``model_``, ``result_`` and ``fitted_`` (a :class:`~hamgrav.fitted.FittedModel`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .bodies import Body, load_body
from .fitted import FittedModel
from .model import Model
from .sensitivity import ArcProblem
from .shape_prior import DEFAULT_PRIOR_MASCONS, fit_shape_prior
from .solvers import Adam, LevenbergMarquardt, scan_kaula, split_validation
from .terms import MasconTerm, NeuralPotential, PointMass, SphericalHarmonics
from .tracking import Arcs

__all__ = ["GravityEstimator", "body_for_arcs", "body_in_frame", "noise_sigmas"]


def body_in_frame(body_name: str, origin_m) -> Body:
    """A body with its frame origin at ``origin_m`` (mesh frame, metres)."""
    return replace(load_body(body_name), origin_m=tuple(float(v) for v in origin_m))


def body_for_arcs(arcs: Arcs) -> Body:
    """The arcs' body, in the arcs' frame (the truth's centre of mass)."""
    return body_in_frame(arcs.body_name, arcs.body_origin_m)


def noise_sigmas(arcs: Arcs) -> np.ndarray:
    """Per-component noise of canonical (q, p) samples: sigma_r, and sigma_v for momenta
    (the position noise's contribution to p through omega x q is of the same order as
    sigma_v and is neglected here)."""
    units = body_units(arcs)
    sr = float(units.to_length(arcs.sigma_r_m))
    sv = float(units.to_velocity(arcs.sigma_v_m_s))
    return np.array([sr, sr, sr, sv, sv, sv])


def body_units(arcs: Arcs):
    from .units import CanonicalUnits

    return CanonicalUnits(arcs.gm_m3_s2, arcs.spin_period_s)


class GravityEstimator:
    """Fit a gravity correction to tracking arcs.

    Args:
        term: "network" or "sh".
        hidden: hidden layer sizes of the network.
        degree: SH degree (reference radius = the body's Brillouin radius).
        prior: None (central term only) or "shape" (constant-density shape prior in the known
            part; the term then learns the interior residual).
        prior_mascons: mascons of the shape prior.
        solver: "lm" or "adam" (default: "lm" for SH, "adam" for the network).
        weighted: divide residual components by their noise sigmas.
        kaula: None, a Kaula weight alpha, or "scan" (needs ``kaula_metric``).
        kaula_metric: callable(params, model) -> score for the scan (lower is better).
        validation_fraction: arcs held out for validation (network fits).
        lm_max_iter, adam_steps, learning_rate, batch_size: solver settings.
        seed: seeds initialisation, validation split and mini-batches.
    """

    def __init__(
        self,
        term="network",
        *,
        hidden=(24, 24),
        degree=4,
        prior=None,
        prior_mascons=DEFAULT_PRIOR_MASCONS,
        solver=None,
        weighted=False,
        kaula=None,
        kaula_metric=None,
        validation_fraction=0.12,
        lm_max_iter=50,
        adam_steps=1500,
        learning_rate=1e-2,
        batch_size=24,
        seed=0,
    ):
        self.term = term
        self.hidden = hidden
        self.degree = degree
        self.prior = prior
        self.prior_mascons = prior_mascons
        self.solver = solver
        self.weighted = weighted
        self.kaula = kaula
        self.kaula_metric = kaula_metric
        self.validation_fraction = validation_fraction
        self.lm_max_iter = lm_max_iter
        self.adam_steps = adam_steps
        self.learning_rate = learning_rate
        self.batch_size = batch_size
        self.seed = seed

    def build_model(self, arcs: Arcs) -> tuple[Model, dict]:
        if self.term not in ("network", "sh"):
            raise ValueError(f"term must be 'network' or 'sh', got {self.term!r}")
        body = body_for_arcs(arcs)
        prior_info: dict = {"kind": "point-mass"}
        if self.prior is None:
            known = (PointMass(),)
        elif self.prior == "shape":
            mascons, report = fit_shape_prior(body, self.prior_mascons, seed=self.seed)
            # centred on its own centre of mass, like the arcs' frame (paper, residual mode)
            mascons = mascons.translated(-mascons.centre_of_mass)
            known = (MasconTerm(mascons, "shape prior"),)
            prior_info = {"kind": "shape", **report}
        else:
            raise ValueError(f"prior must be None or 'shape', got {self.prior!r}")
        if self.term == "network":
            learnable = NeuralPotential(tuple(self.hidden))
        else:
            learnable = SphericalHarmonics(int(self.degree), body.brillouin_radius)
        return Model(known, learnable), prior_info

    @property
    def solver_name(self) -> str:
        """The solver in use: as given, else Adam for the network and LM for SH."""
        return self.solver or ("adam" if self.term == "network" else "lm")

    def _solver(self):
        name = self.solver_name
        if name == "lm":
            alpha = self.kaula if isinstance(self.kaula, int | float) else 0.0
            return LevenbergMarquardt(max_iter=self.lm_max_iter, kaula_alpha=float(alpha))
        if name == "adam":
            return Adam(
                learning_rate=self.learning_rate,
                steps=self.adam_steps,
                batch_size=self.batch_size,
                seed=self.seed,
            )
        raise ValueError(f"solver must be 'lm' or 'adam', got {name!r}")

    def fit(
        self,
        arcs: Arcs,
        *,
        init: np.ndarray | None = None,
        callback=None,
        checkpoint=None,
        resume: dict | None = None,
    ):
        model, prior_info = self.build_model(arcs)
        problem = ArcProblem(model, arcs, sigmas=noise_sigmas(arcs) if self.weighted else None)
        solver = self._solver()
        if init is None:
            init = model.learnable.initial_params(self.seed)
        elif len(init) != problem.n_params:
            raise ValueError(
                f"initial parameters have {len(init)} entries; this model needs {problem.n_params}"
            )
        use_validation = self.term == "network" and self.validation_fraction > 0
        train = validation = None
        if use_validation:
            train, validation = split_validation(arcs.n_arcs, self.validation_fraction, self.seed)
        kaula_scores = None
        if self.kaula == "scan":
            if self.kaula_metric is None:
                raise ValueError("kaula='scan' needs kaula_metric(params, model)")
            alpha, result, kaula_scores = scan_kaula(
                problem, lambda c: self.kaula_metric(c, model), solver=solver, theta0=init
            )
            solver = LevenbergMarquardt(**{**solver.__dict__, "kaula_alpha": alpha})
        else:
            result = solver.solve(
                problem,
                init,
                train=train,
                validation=validation,
                callback=callback,
                checkpoint=checkpoint,
                resume=resume,
            )
        self.model_ = model
        self.params_ = result.params
        self.result_ = result
        solver_info = {
            **solver.describe(),
            "weighted": self.weighted,
            "validation_fraction": self.validation_fraction if use_validation else 0,
            "seed": self.seed,
            "message": result.message,
            "iterations": result.iterations,
            "wall_s": result.wall_s,
            "n_arcs": arcs.n_arcs,
        }
        if kaula_scores is not None:
            solver_info["kaula_scan"] = kaula_scores
        history = {k: [float(x) for x in v] for k, v in result.history.items()}
        self.fitted_ = FittedModel(
            model=model,
            params=result.params,
            body_name=arcs.body_name,
            gm_m3_s2=arcs.gm_m3_s2,
            spin_period_s=arcs.spin_period_s,
            body_origin_m=tuple(arcs.body_origin_m),
            prior=prior_info,
            solver=solver_info,
            history=history,
        )
        return self

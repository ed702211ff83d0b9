"""Formal uncertainty of the learned potential at points (canonical units, no I/O).

With C the covariance of the learnable parameters theta (see
:func:`hamgrav.fit.covariance.formal_covariance`) and g(q) = dN(q) / d theta the gradient of
the learned potential at q with respect to them, the linearised standard deviation of the
potential at q is

    sigma_V(q) = sqrt(g(q)^T C g(q)).

For an SH term N is linear in theta, so this is exact given C; for a network it is a
linearisation. sigma_V covers the noise propagated through the fit only: not the
truncation (omission) of an SH expansion, nor the known part.
"""

from __future__ import annotations

import heyoka as hy
import numpy as np

from .hamiltonian import POSITION
from .model import Model, _cached

__all__ = ["potential_gradient_function", "potential_gradient", "potential_sigma"]


def potential_gradient_function(model: Model):
    """Compiled (cached) dN/dtheta of the learnable term at body-fixed points: a heyoka
    ``cfunc`` with outputs (dN/dtheta_0, ..., dN/dtheta_{n-1}), inputs (x, y, z) and the
    learnable parameters as its ``pars``."""

    def build():
        if model.learnable is None or model.n_learn == 0:
            raise ValueError("the model has no learnable parameters")
        v = model.learnable.potential(0)
        grad = hy.diff_tensors([v], diff_args=hy.diff_args.params, diff_order=1).jacobian
        outputs = [grad[0, j] for j in range(model.n_learn)]
        return hy.cfunc(outputs, vars=list(POSITION), compact_mode=True)

    return _cached((model.key(), "potential-gradient"), build)


def potential_gradient(model: Model, params: np.ndarray, points: np.ndarray) -> np.ndarray:
    """g (k, n_learn): dN/dtheta at ``points`` (k, 3) [canonical], ``params[:n_learn]``."""
    f = potential_gradient_function(model)
    points = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=float)).T)
    if f.nparams == 0:  # linear in theta (SH): the gradient does not depend on it
        return f(points).T
    # the gradient of a network does not contain its output biases (N is linear in them):
    # the compiled function counts parameters up to the last one it uses
    theta = np.asarray(params, float)[: f.nparams, None]
    pars = np.ascontiguousarray(np.broadcast_to(theta, (f.nparams, points.shape[1])))
    return f(points, pars=pars).T


def potential_sigma(
    model: Model,
    params: np.ndarray,
    covariance: np.ndarray,
    points: np.ndarray,
    chunk: int = 2048,
) -> np.ndarray:
    """sigma_V (k,) [canonical potential] at ``points`` (k, 3): sqrt(g^T C g) with C
    (n_learn, n_learn) the parameters' covariance (module docstring); ``chunk`` points at a
    time."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    covariance = np.asarray(covariance, dtype=float)
    var = np.empty(len(points))
    for i in range(0, len(points), chunk):  # g is (k, n_learn): bounded memory for networks
        g = potential_gradient(model, params, points[i : i + chunk])
        var[i : i + chunk] = np.einsum("ki,ki->k", g @ covariance, g)
    return np.sqrt(np.clip(var, 0.0, None))

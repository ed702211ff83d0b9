"""A network model as a framework-free JSON file: everything needed to evaluate its potential.

The file (``"format": "hamgrav-network"``) holds, in canonical units (length = the
synchronous radius, time = spin period / 2 pi, so GM = 1; ``units`` gives their SI values)
and in the body-fixed frame of the fit (z along the spin axis, origin ``body.origin_m`` in
the shape model's frame):

- ``known``: the known part of the potential, a list of terms: ``{"kind": "point-mass",
  "mu"}`` (mu / r: the central term) or ``{"kind": "mascons", "positions" (n, 3),
  "masses" (n,)}`` (sum m_i / |q - q_i|: a shape prior, whose masses sum to 1 and so
  carries the central term), and with a shape prior left in place ``{"kind": "point-dipole",
  "moment" (3,)}`` ((d . q) / |q|^3: what brings the known part's centre of mass back to the
  origin);
- ``network``: the learned correction N(q) = scale * (envelope_radius / rho)^3 * NN(q),
  rho = sqrt(|q|^2 + envelope_softening^2) (files written before the softening existed have
  none: rho = |q|), NN
  the mean over ``members`` of a fully connected network with inputs (x, y, z), tanh hidden
  layers and one linear output: x_{k+1} = tanh(W_k x_k + b_k), output W x + b, with
  ``weights[k]`` of shape (out, in) and ``biases[k]`` of shape (out,);
- the potential is V(q) = sum of the known terms + N(q), positive (the acceleration is
  grad V), in units of ``units.potential_m2_s2``.

Per-trajectory terms (e.g. SRP) are not gravity and are not written. The README's "Import
and export" section holds a short numpy function that evaluates the file; a test checks it
against hamgrav to 1e-12.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from .. import __version__
from ..errors import InputError
from ..files import atomic_path
from ..fit.fitted import FittedModel
from ..units import CanonicalUnits

__all__ = ["NETWORK_FORMAT", "network_document", "write_network_json"]

NETWORK_FORMAT = "hamgrav-network"
NETWORK_FORMAT_VERSION = 1


def network_document(fitted: FittedModel) -> dict:
    """The JSON document (plain data) of a network model (see the module docstring)."""
    model = fitted.model
    term = model.learnable
    entry = None if term is None else term.export_json(fitted.learnable_params)
    if entry is None:
        kind = "none (the known part alone)" if term is None else term.title
        raise InputError(
            f"the JSON export is for network models, this one's learnable term is {kind}; "
            "export spherical harmonics with --format icgem or shadr"
        )
    units = CanonicalUnits(fitted.gm_m3_s2, fitted.spin_period_s)
    known = []
    for t in model.known:
        known_entry = t.export_json()
        if known_entry is None:
            raise InputError(f"cannot export a known term of kind {t.key()!r}")
        known.append(known_entry)
    return {
        "format": NETWORK_FORMAT,
        "format_version": NETWORK_FORMAT_VERSION,
        "hamgrav_version": __version__,
        "description": (
            "V(q) = sum of the known terms + N(q), positive (acceleration = grad V), canonical "
            "units; N(q) = scale * (envelope_radius / rho)^3 * mean over members of NN(q), rho = "
            "sqrt(|q|^2 + envelope_softening^2); NN: "
            "x_{k+1} = tanh(W_k x_k + b_k) on hidden layers, linear output; weights[k] is "
            "(out, in); point-mass: mu / |q|; mascons: sum m_i / |q - q_i|; point-dipole: "
            "(d . q) / |q|^3"
        ),
        "body": {
            "name": fitted.body_name,
            "gm_m3_s2": fitted.gm_m3_s2,
            "spin_period_s": fitted.spin_period_s,
            "frame": "body-fixed, z along the spin axis, rotating with the body",
            "origin_m": list(fitted.body_origin_m),
        },
        "units": {
            "canonical": "length = synchronous radius (GM / omega^2)^(1/3), time = spin "
            "period / 2 pi, so GM = omega = 1",
            "length_m": units.length_m,
            "time_s": units.time_s,
            "potential_m2_s2": units.potential_m2_s2,
            "acceleration_m_s2": units.acceleration_m_s2,
        },
        "known": known,
        # under the term's registered name: "network" (the one learnable term with an entry)
        term.kind: entry,
        "prior": fitted.prior.get("kind") if isinstance(fitted.prior, dict) else None,
        "not_included": [t.key() for t in model.per_trajectory],
    }


def write_network_json(fitted: FittedModel, path: str | os.PathLike) -> Path:
    """Write the JSON document of a network model to ``path`` (atomically)."""
    path = Path(path)
    doc = network_document(fitted)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return path

"""A model and the arcs it belongs with: finding the arcs file a model was fitted to (the
one it records, or one given), reading it and refusing arcs of another body, body model,
frame or truth; the formal covariance of an SH model from those arcs.

These read files, so they live here and not on :class:`~hamgrav.fit.fitted.FittedModel`,
whose checks (:meth:`~hamgrav.fit.fitted.FittedModel.check_arcs`,
:meth:`~hamgrav.fit.fitted.FittedModel.check_truth`) they call.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..core.arcs import Arcs
from ..errors import InputError
from ..fit.fitted import FittedModel
from . import arcs as arcs_io  # looked up at each call, as the CLI did

__all__ = ["truth_arcs", "sh_formal_covariance"]


def truth_arcs(
    fitted: FittedModel, model_file: str | os.PathLike, arcs_file: str | os.PathLike | None = None
) -> Arcs:
    """The arcs whose truth ``fitted`` (read from ``model_file``, which names it in
    messages) is compared with: ``arcs_file`` when given, else the file recorded at the fit
    (:meth:`FittedModel.recorded_arcs_file`). Refused (:class:`InputError`) unless a file is
    known and there, and it holds arcs of the model's body, body model (GM [m^3/s^2], spin
    period [s]), frame and truth (:meth:`FittedModel.check_arcs`,
    :meth:`FittedModel.check_truth`; a model that records no truth digest is compared with a
    warning)."""
    source = arcs_file or fitted.recorded_arcs_file()
    if not source:
        raise InputError(f"model file {model_file} records no arcs file; pass --arcs ARCS")
    if not isinstance(source, str | os.PathLike):
        raise InputError(
            f"model file {model_file} records its arcs file as {source!r}, not a path; pass "
            "--arcs ARCS"
        )
    if arcs_file is None and not Path(source).exists():
        raise InputError(
            f"the arcs file model {model_file} was fitted to, {source}, is gone; pass the "
            "campaign's arcs with --arcs ARCS"
        )
    arcs = arcs_io.load_arcs(source)
    fix = "pass the arcs of this model's campaign with --arcs"
    fitted.check_arcs(arcs, source, f"model {model_file}", fix)
    fitted.check_truth(arcs, source, f"model {model_file}", fix, f"model file {model_file}")
    return arcs


def sh_formal_covariance(
    fitted: FittedModel, arcs_file: str | os.PathLike | None = None
) -> tuple[np.ndarray | None, str]:
    """(C, note): the a priori formal covariance C (n_learn, n_learn) [canonical] of an SH
    model's learnable parameters from its arcs (``arcs_file``, else the file recorded at the
    fit), and a note in words of where it came from; (None, why not) when the model has
    per-trajectory terms, the fit's arcs file is not there, or the arcs record no tracking
    noise. Arcs of another body, body model or frame are refused (:class:`InputError`)."""
    from ..fit.covariance import formal_covariance
    from ..fit.estimator import has_noise

    if fitted.model.per_trajectory:
        return None, "no formal errors: the model has per-trajectory terms (e.g. SRP)"
    source = arcs_file or fitted.recorded_arcs_file()
    if not isinstance(source, str | os.PathLike) or (
        arcs_file is None and not Path(source).is_file()
    ):
        return None, "no formal errors: the fit's arcs file is not there (pass --arcs ARCS)"
    arcs = arcs_io.load_arcs(source)
    fitted.check_arcs(
        arcs,
        source,
        "the model",
        "pass the model's arcs with --arcs, or export without formal errors (--no-errors)",
    )
    if not has_noise(arcs):
        return None, f"no formal errors: {source} records no tracking noise (noise-free arcs)"
    return formal_covariance(fitted, arcs), f"formal errors from {source}"

"""A fit that writes its model file, keeps a checkpoint beside it while it runs, and can be
resumed from that checkpoint or continue an earlier model: what ``hamgrav fit`` does, with
the same checks, callable from Python.

    run = prepare_fit(estimator, arcs, "model.h5", init="stage0.h5", resume=False)
    run.run(arcs_file="arcs.h5")  # fit (or continue), write model.h5, drop the checkpoint

or in one call, :func:`fit_to_file`. The checkpoint is ``<model>.checkpoint.npz``
(:func:`hamgrav.io.models.checkpoint_path_for`); it records the fit's identity
(:meth:`GravityEstimator.checkpoint_identity`), and a checkpoint of another fit (other
arcs, body, settings, solver or starting model) is not resumed.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.arcs import Arcs
from ..errors import HamgravError, InputError
from ..files import check_output
from ..fit.anchor import AnchorSettings
from ..fit.estimator import GravityEstimator
from ..fit.fitted import FittedModel
from . import arcs as arcs_io
from . import models  # looked up at each call (tests replace save_checkpoint)

__all__ = [
    "FitRun",
    "checkpoint_for_fit",
    "checkpoint_progress",
    "continued_model",
    "fit_to_file",
    "prepare_fit",
]


def checkpoint_for_fit(output: str | os.PathLike, resume: bool) -> Path:
    """The checkpoint of a fit that writes the model file ``output``, checked before any
    work: with ``resume`` it must exist; without, none may be there (an interrupted fit's
    checkpoint is not started over); and it must be writable
    (:func:`hamgrav.files.check_output`). Raises :class:`InputError` otherwise."""
    ckpt = models.checkpoint_path_for(output)
    if resume and not ckpt.exists():
        raise InputError(f"no checkpoint {ckpt} to resume from; run without --resume")
    if not resume and (ckpt.exists() or ckpt.is_symlink()):
        raise InputError(
            f"a checkpoint of an interrupted fit exists: {ckpt}; continue that fit with the "
            "same command and --resume, or delete the checkpoint to start afresh"
        )
    check_output(ckpt, "checkpoint", {})
    return ckpt


def continued_model(
    path: str | os.PathLike, estimator: GravityEstimator, arcs: Arcs, name: str | None = None
) -> FittedModel:
    """The model file at ``path`` read as the start of a continual stage of ``estimator`` on
    ``arcs``, refused unless it has the estimator's structure and the arcs' body and frame
    (:meth:`GravityEstimator.check_continuation`). Errors name it ``name`` (default: "model
    to continue <path>") in front of the message."""
    try:
        previous = models.load_model(path)
        estimator.check_continuation(previous, arcs)
    except HamgravError as exc:  # name the model being continued
        raise type(exc)(f"{name or f'model to continue {path}'}: {exc}") from None
    return previous


def checkpoint_progress(ckpt: str | os.PathLike) -> str:
    """Where the fit kept in checkpoint ``ckpt`` stands, in words (e.g. "Adam step 75",
    "network 2 of the ensemble, LM iteration 4")."""
    try:
        _, state = models.load_checkpoint(ckpt)
    except HamgravError as exc:  # not expected: checkpoints are written whole or not at all
        return f"unreadable: {exc}"
    where = []
    if "member" in state:
        where.append(f"network {int(state['member']) + 1} of the ensemble")
    if "step" in state:
        where.append(f"Adam step {int(state['step'])}")
    elif "iteration" in state:
        where.append(f"LM iteration {int(state['iteration'])}")
    return ", ".join(where) or "its solver's last state"


@dataclass
class FitRun:
    """A prepared fit of ``estimator`` on ``arcs`` that writes the model file ``output``
    (see :func:`prepare_fit`).

    Attributes:
        checkpoint: the checkpoint file beside ``output``, written as the fit goes.
        previous: the model a continual stage starts from (None: a fit from scratch).
        identity: the fit's checkpoint identity (plain data).
        init, state: the parameters and solver state of a resumed checkpoint (None: not
            resumed).
        arc_weights: each arc's weight in the cost (None: all 1; see
            :meth:`GravityEstimator.fit`).
        anchor: a continued fit's field anchor
            (:meth:`GravityEstimator.continue_fit`; None: none).
    """

    estimator: GravityEstimator
    arcs: Arcs
    output: Path
    checkpoint: Path
    previous: FittedModel | None
    identity: dict
    init: np.ndarray | None = None
    state: dict | None = None
    arc_weights: np.ndarray | None = None
    anchor: AnchorSettings | None = None

    def fit(self, callback=None) -> GravityEstimator:
        """Fit (or continue ``previous``; resume the checkpoint when one was read), saving
        the checkpoint as the solver goes; ``callback(iteration, record)`` as
        :meth:`GravityEstimator.fit`. Returns the fitted estimator."""
        how = {
            "init": self.init,
            "callback": callback,
            "checkpoint": lambda th, st: models.save_checkpoint(
                self.checkpoint, th, st, self.identity
            ),
            "resume": self.state,
            "arc_weights": self.arc_weights,
        }
        if self.anchor is not None and self.previous is None:
            raise InputError("the field anchor holds a continued fit: give the model to continue")
        if self.previous is not None:
            return self.estimator.continue_fit(self.previous, self.arcs, anchor=self.anchor, **how)
        return self.estimator.fit(self.arcs, **how)

    def write(self, arcs_file: str | os.PathLike | None = None) -> FittedModel:
        """Write the fitted model to ``output`` (recording ``arcs_file``, the file of the
        arcs, when given) and remove the checkpoint, now stale. Returns the model written."""
        fitted = self.estimator.fitted_
        if arcs_file is not None:
            fitted = fitted.with_arcs_file(arcs_file)
        models.save_model(fitted, self.output)
        self.checkpoint.unlink(missing_ok=True)
        return fitted

    def run(self, arcs_file: str | os.PathLike | None = None, callback=None) -> FittedModel:
        """:meth:`fit`, then :meth:`write`."""
        self.fit(callback)
        return self.write(arcs_file)


def prepare_fit(
    estimator: GravityEstimator,
    arcs: Arcs,
    output: str | os.PathLike,
    *,
    init: str | os.PathLike | FittedModel | None = None,
    resume: bool = False,
    checkpoint: Path | None = None,
    init_name: str | None = None,
    arc_weights: np.ndarray | None = None,
    anchor: AnchorSettings | None = None,
) -> FitRun:
    """Everything ``hamgrav fit`` checks before a fit starts, as a :class:`FitRun`: the
    checkpoint beside ``output`` (:func:`checkpoint_for_fit`; pass ``checkpoint`` when it was
    checked already), the model to continue ``init`` (a model file or a
    :class:`FittedModel`: :meth:`GravityEstimator.check_continuation`; ``init_name`` names
    it in errors), the fit's identity (its arcs, body, settings, solver: the warm solver of
    a continued fit, and its starting model, the ``arc_weights`` and the ``anchor`` of a
    continued fit when given) and, with ``resume``, the checkpoint read and refused if
    another fit wrote it."""
    output = Path(output)
    ckpt = checkpoint if checkpoint is not None else checkpoint_for_fit(output, resume)
    previous = init
    if isinstance(init, str | os.PathLike):
        previous = continued_model(init, estimator, arcs, init_name)
    elif init is not None:
        estimator.check_continuation(init, arcs)
    solver = (estimator.warm_solver if previous is not None else None) or estimator.make_solver()
    identity = estimator.checkpoint_identity(arcs, solver, init=previous)
    if arc_weights is not None:
        arc_weights = np.asarray(arc_weights, dtype=float)
        identity["arc_weights_sha256"] = _sha256(arc_weights)
    if anchor is not None:
        if previous is None:
            raise InputError(
                "the field anchor holds a continued fit near the model it continues: give "
                "the model to continue (--init)"
            )
        # refused here, before a cluster or the progress starts: what the fit would refuse
        estimator.check_anchor_allowed(solver)
        estimator.continuation_anchor(previous, arcs, anchor)
        # the points follow from the arcs (in the identity already) and the clearance
        identity["anchor"] = {
            "weight": anchor.weight,
            "clearance": anchor.clearance,
            "quantity": anchor.quantity,
            **({} if anchor.clear_of is None else {"clear_of_sha256": _sha256(anchor.clear_of)}),
        }
    run = FitRun(
        estimator, arcs, output, ckpt, previous, identity, arc_weights=arc_weights, anchor=anchor
    )
    if resume:
        run.init, run.state = models.load_checkpoint(ckpt, expect=identity)
    return run


def _sha256(values: np.ndarray) -> str:
    """SHA-256 (hex) of an array's float64 bytes."""
    return hashlib.sha256(np.ascontiguousarray(values, dtype=np.float64).tobytes()).hexdigest()


def fit_to_file(
    estimator: GravityEstimator,
    arcs: Arcs | str | os.PathLike,
    output: str | os.PathLike,
    *,
    init: str | os.PathLike | FittedModel | None = None,
    resume: bool = False,
    callback=None,
    arc_weights: np.ndarray | None = None,
    anchor: AnchorSettings | None = None,
) -> FittedModel:
    """Fit ``estimator`` to ``arcs`` (an arcs file, recorded in the model, or
    :class:`Arcs`) and write the model file ``output``, as ``hamgrav fit`` does: a checkpoint
    beside it while it runs (kept if the fit is stopped), ``resume`` to continue from it,
    ``init`` (a model file or :class:`FittedModel`) to continue that model as a continual
    stage; ``arc_weights`` each arc's weight in the cost (:meth:`GravityEstimator.fit`);
    ``anchor`` holds a continued model's field where the new arcs do not reach
    (:meth:`GravityEstimator.continue_fit`). Returns the model written."""
    # (output may be the model of init: it is continued in place)
    check_output(Path(output), "output", {} if isinstance(arcs, Arcs) else {"arcs": arcs})
    ckpt = checkpoint_for_fit(output, resume)
    arcs_file = None
    if not isinstance(arcs, Arcs):
        arcs_file, arcs = arcs, arcs_io.load_arcs(arcs)
    run = prepare_fit(
        estimator,
        arcs,
        output,
        init=init,
        resume=resume,
        checkpoint=ckpt,
        arc_weights=arc_weights,
        anchor=anchor,
    )
    return run.run(arcs_file, callback)

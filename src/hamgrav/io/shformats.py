"""Gravity-field coefficient files: a fitted model as ICGEM (GFC) or SHADR (PDS) text.

What is written is the model's whole gravitational potential (the central term, the known
part such as a shape prior, and the learned correction; not per-trajectory terms such as
SRP) as a fully normalised exterior expansion (4-pi geodesy normalisation, no
Condon-Shortley phase, positive potential) in the body-fixed frame of the fit (z along the
spin axis, origin ``body_origin_m`` in the shape model's frame):

    V(r, lat, lon) = GM / r * sum_{l=0..L} (R / r)^l sum_m P_lm(sin lat)
                     (C_lm cos(m lon) + S_lm sin(m lon)),

GM [m^3/s^2] the body's, R [m] the reference radius, C00 = 1 (the central term; a shape
prior's mascons sum to 1 too) and degree 1 from the known part (0 for a point mass: the
frame is centred on the centre of mass). How each part is turned into coefficients
(:mod:`hamgrav.core.shexpansion`): an SH model's own coefficients exactly; a shape prior's
mascons exactly, truncated at L; a network by projection on the sphere r = R. The file
states which, and the relative RMS difference between the file's field and hamgrav's
perturbing potential (everything but GM/r) on the sphere r = R and at 1.5 R.

Formal errors (when a covariance is given, SH models only; see
:mod:`hamgrav.fit.covariance`) are the square roots of the diagonal, in the same
normalisation; the known part has none (zero).

ICGEM: the free-text description comes first, before ``begin_of_head``; the keyword lines
last, because pyshtools' reader matches keywords anywhere in a header line and keeps the
last match. SHADR: the PDS ASCII table (a header record R [km], GM [km^3/s^2], sigma GM,
degree, order, normalisation state 1, reference longitude and latitude 0; then l, m, C, S,
sigma C, sigma S), which has no room for text: the conventions are those above.
"""

from __future__ import annotations

import datetime as dt
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.fields import central_potential, shell_points
from ..core.model import evaluate_field
from ..core.shexpansion import (
    empty_tables,
    project_on_sphere,
    quadrature_points,
    relative_rms,
    sh_potential,
)
from ..errors import InputError
from ..files import atomic_path
from ..fit.fitted import FittedModel
from ..units import CanonicalUnits

__all__ = [
    "SHExport",
    "sh_export",
    "model_export",
    "write_icgem",
    "write_shadr",
    "CHECK_RADII",
    "PROJECTION_DEGREE",
]

#: SH degree a model that is not an SH expansion (a network) is projected at by default.
PROJECTION_DEGREE = 8

#: Radii (in reference radii) where the written field is compared with the model.
CHECK_RADII = (1.0, 1.5)


@dataclass(frozen=True, eq=False)
class SHExport:
    """A model's potential as SH coefficients, ready to write.

    Attributes:
        c, s: (L + 1, L + 1) fully normalised coefficients [dimensionless], [l, m].
        sigma_c, sigma_s: their formal errors (zeros when there are none).
        gm_m3_s2: GM [m^3/s^2] the coefficients are scaled by.
        reference_radius_m: R [m].
        body_name, spin_period_s [s], body_origin_m [m]: the body and its frame.
        contents: one line per part of the model: what it is and how it was converted.
        errors: "formal" or "no".
        accuracy: relative RMS difference of the file's perturbing potential from the
            model's on the shells r = k R, keyed "r<k>R" (k in :data:`CHECK_RADII`).
        method: "exact" when every part is converted exactly, else "approximate".
    """

    c: np.ndarray
    s: np.ndarray
    sigma_c: np.ndarray
    sigma_s: np.ndarray
    gm_m3_s2: float
    reference_radius_m: float
    body_name: str
    spin_period_s: float
    body_origin_m: tuple[float, float, float]
    contents: list[str]
    errors: str
    accuracy: dict[str, float] = field(default_factory=dict)
    method: str = "exact"

    @property
    def degree(self) -> int:
        """L, the maximum degree."""
        return self.c.shape[0] - 1


def sh_export(
    fitted: FittedModel,
    *,
    degree: int | None = None,
    reference_radius: float | None = None,
    covariance: np.ndarray | None = None,
    n_lat: int | None = None,
) -> SHExport:
    """The potential of ``fitted`` (central term, known part, learned correction) as SH
    coefficients (see the module docstring).

    Args:
        fitted: the model.
        degree: L (default: the SH model's degree; required for other models).
        reference_radius: R [canonical] (default: the SH model's; required otherwise, e.g.
            the body's Brillouin radius).
        covariance: formal covariance (n_learn, n_learn) of an SH model's parameters
            [canonical] (see :func:`hamgrav.fit.covariance.formal_covariance`).
        n_lat: Gauss-Legendre latitude rings of a projection (default 2 L + 34).
    """
    model = fitted.model
    term = model.learnable
    own = None if term is None else term.expansion()
    if own is not None:
        degree = own[0] if degree is None else degree
        reference_radius = own[1] if reference_radius is None else reference_radius
    if degree is None or reference_radius is None:
        raise InputError("give the degree and the reference radius of the expansion")
    degree = int(degree)
    if degree < 2:
        raise InputError(f"the degree must be at least 2, got {degree}")
    if not reference_radius > 0:
        raise InputError(f"the reference radius must be positive, got {reference_radius}")
    units = CanonicalUnits(fitted.gm_m3_s2, fitted.spin_period_s)
    c, s = empty_tables(degree)
    sig_c, sig_s = empty_tables(degree)
    contents, exact = [], True
    for known in model.known:
        part = known.sh_tables(None, degree, reference_radius)
        if part is None:
            raise InputError(f"cannot export a known term of kind {known.key()!r}")
        c, s = c + part.c, s + part.s
        exact = exact and part.exact
        contents.append(part.note)
    params = fitted.learnable_params
    part = None if term is None else term.sh_tables(params, degree, reference_radius)
    if part is not None:
        c, s = c + part.c, s + part.s
        exact = exact and part.exact
        contents.append(part.note)
        if covariance is not None:
            # the tables are linear in the parameters: the errors map as the coefficients do
            sig = np.sqrt(np.clip(np.diag(np.asarray(covariance, dtype=float)), 0.0, None))
            errors = term.sh_tables(sig, degree, reference_radius)
            sig_c, sig_s = np.abs(errors.c), np.abs(errors.s)
    elif term is not None:
        if covariance is not None:
            raise InputError(f"formal errors of a projected {term.title} are not available")

        def learned(points):
            return evaluate_field(model, fitted.params, points, which="learnable")[0]

        pc, ps = project_on_sphere(learned, degree, reference_radius, n_lat)
        c, s = c + pc, s + ps
        exact = False
        rings = int(n_lat or len(quadrature_points(degree, reference_radius)[1]) ** 0.5 / 2**0.5)
        contents.append(
            f"learned {term.title} correction ({term.n_params} parameters): projected on the "
            f"sphere r = R by Gauss-Legendre quadrature ({rings} x {2 * rings} nodes) to "
            f"degree {degree}; the {term.title} is neither band-limited nor exactly harmonic, "
            "see the accuracy lines"
        )
    if model.per_trajectory:
        contents.append("not included: per-trajectory terms (e.g. SRP), which are not gravity")

    accuracy = {}
    for k in CHECK_RADII:
        pts = shell_points(k * reference_radius, 400, seed=1)
        v_model = evaluate_field(model, fitted.params, pts, which="total")[0]
        v_file = sh_potential(c, s, reference_radius, pts)
        central = central_potential(pts)
        accuracy[f"r{k:g}R"] = relative_rms(v_file - central, v_model - central)
    has_errors = covariance is not None and part is not None
    return SHExport(
        c=c,
        s=s,
        sigma_c=sig_c,
        sigma_s=sig_s,
        gm_m3_s2=float(fitted.gm_m3_s2),
        reference_radius_m=float(units.from_length(reference_radius)),
        body_name=fitted.body_name,
        spin_period_s=float(fitted.spin_period_s),
        body_origin_m=tuple(float(v) for v in fitted.body_origin_m),
        contents=contents,
        errors="formal" if has_errors else "no",
        accuracy=accuracy,
        method="exact" if exact else "approximate",
    )


def model_export(
    fitted: FittedModel,
    *,
    degree: int | None = None,
    body=None,
    covariance: np.ndarray | None = None,
) -> SHExport:
    """:func:`sh_export` with the export policy of ``hamgrav export``: an SH model at its own
    reference radius and (default) degree; any other model (a network) projected at
    ``degree`` (default :data:`PROJECTION_DEGREE`) on the sphere at the Brillouin radius
    [canonical] of ``body`` (a :class:`~hamgrav.bodies.catalogue.Body` in the model's frame;
    default: the body the model was fitted for). ``covariance``: as :func:`sh_export`."""
    if fitted.sh_expansion() is not None:
        return sh_export(fitted, degree=degree, covariance=covariance)
    if body is None:
        from ..fit.estimator import body_for_model

        body = body_for_model(fitted)
    return sh_export(
        fitted,
        degree=PROJECTION_DEGREE if degree is None else degree,
        reference_radius=body.brillouin_radius,
        covariance=covariance,
    )


def _description(exp: SHExport, source: str) -> list[str]:
    origin = ", ".join(repr(v) for v in exp.body_origin_m)
    lines = [
        f"hamgrav gravity field of {exp.body_name}, from {source}",
        f"written {dt.datetime.now(dt.UTC).strftime('%Y-%m-%dT%H:%M:%SZ')}",
        "field: V = GM/r sum_l (R/r)^l sum_m P_lm(sin lat) (C_lm cos m lon + S_lm sin m lon),"
        " positive, exterior to the sphere r = R",
        "P_lm: 4-pi fully normalised (geodesy), no Condon-Shortley phase; S_l0 = 0",
        "central term included: C00 = 1 (GM is the whole body's)",
        f"frame: body-fixed, z along the spin axis, rotating with the body (sidereal period "
        f"{exp.spin_period_s!r} s); origin at ({origin}) m in the shape model's frame",
        "tides: none modelled (a rigid body), so tide_free",
        *(f"part: {c}" for c in exp.contents),
        *(
            f"accuracy: relative RMS of (file - hamgrav) perturbing potential on r = {k[1:-1]} R:"
            f" {v:.3e}"
            for k, v in exp.accuracy.items()
        ),
        (
            "sigmas: formal, sqrt of the diagonal of the least-squares covariance under the "
            "tracking noise (white, plus each arc's noisy first sample); no model error"
            if exp.errors == "formal"
            else "sigmas: none"
        ),
    ]
    return lines


def write_icgem(exp: SHExport, path: str | os.PathLike, *, source: str = "a hamgrav model") -> Path:
    """Write ``exp`` as an ICGEM GFC file at ``path`` (atomically); see the module docstring."""
    path = Path(path)
    lines = _description(exp, source)
    lines += [
        "begin_of_head ================================================================",
        "product_type            gravity_field",
        f"modelname               hamgrav_{exp.body_name}",
        f"earth_gravity_constant  {exp.gm_m3_s2:.17e}",
        f"radius                  {exp.reference_radius_m:.17e}",
        f"max_degree              {exp.degree}",
        f"errors                  {exp.errors}",
        "norm                    fully_normalized",
        "tide_system             tide_free",
        "key   L    M         C                        S"
        + ("                    sigma C         sigma S" if exp.errors != "no" else ""),
        "end_of_head ==================================================================",
    ]
    for l in range(exp.degree + 1):
        for m in range(l + 1):
            row = f"gfc {l:4d} {m:4d} {exp.c[l, m]: .17e} {exp.s[l, m]: .17e}"
            if exp.errors != "no":
                row += f" {exp.sigma_c[l, m]:.6e} {exp.sigma_s[l, m]:.6e}"
            lines.append(row)
    _write_text(path, lines)
    return path


def write_shadr(exp: SHExport, path: str | os.PathLike) -> Path:
    """Write ``exp`` as a PDS SHADR table at ``path`` (atomically): R [km], GM [km^3/s^2]."""
    path = Path(path)
    lines = [
        f"{exp.reference_radius_m / 1e3:.17e}, {exp.gm_m3_s2 / 1e9:.17e}, {0.0:.17e}, "
        f"{exp.degree:5d}, {exp.degree:5d}, 1, {0.0:.17e}, {0.0:.17e}"
    ]
    for l in range(exp.degree + 1):
        for m in range(l + 1):
            lines.append(
                f"{l:5d}, {m:5d}, {exp.c[l, m]: .17e}, {exp.s[l, m]: .17e}, "
                f"{exp.sigma_c[l, m]: .17e}, {exp.sigma_s[l, m]: .17e}"
            )
    _write_text(path, lines)
    return path


def _write_text(path: Path, lines: list[str]) -> None:
    with atomic_path(path) as tmp, open(tmp, "w", encoding="ascii", errors="replace") as f:
        f.write("\n".join(lines) + "\n")
        f.flush()
        os.fsync(f.fileno())

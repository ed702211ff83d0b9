"""Your own body and tracking, no truth: the user's path, scored against a truth it never sees.

A user brings a shape model in kilometres (Gaskell ICQ), GM, spin period and pole in a body
TOML, and a reconstructed trajectory as a SPICE SPK. Each repetition plays that user:

1. writes the shape of a contact binary as an ICQ file in km and its constants in a body
   TOML, in a scratch folder (the shape is sampled on the ICQ cube grid, so it is a new mesh,
   not one of hamgrav's);
2. reads the body back from the TOML (:func:`hamgrav.bodies.files.read_body_toml`) and, as
   the simulator only, builds a truth interior and simulates the tracking;
3. writes the noisy arcs as a type-13 SPK and imports them again as tracking without a
   truth (:func:`hamgrav.io.spk.import_spk`, noise levels given as a user gives them);
4. fits each row to the imported arcs, choosing the model from the arcs alone: SH with the
   degree and Kaula weight chosen by k-fold cross-validation (``sh-auto``), network-best,
   and SH 8 with no choice (a user's first try);
5. scores, with the truth: the fitted field in SI (:meth:`FittedModel.potential` at points
   in metres) on shells and 30 m above the surface, and the exported ICGEM coefficients
   (the file's own numbers, evaluated independently of heyoka) on the shells.

No step looks a body up by name. 1 = no correction; below 1 beats it.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bodies.catalogue import G_SI, contact_binary_radius
from ..bodies.evaluation import evaluation_sets
from ..bodies.files import read_body_toml
from ..bodies.interiors import build_truth
from ..bodies.shapes import read_shape, write_icq
from ..core.fields import relative_field_error
from ..core.mascons import mascon_potential
from ..core.shexpansion import sh_potential
from ..core.terms import SphericalHarmonics
from ..errors import InputError
from ..fit.estimator import DEFAULT_HIDDEN, body_for_model, preset
from ..io.shformats import sh_export, write_icgem
from ..io.spk import import_spk, write_spk
from ..report.own_body import own_body_readme
from ..sim.tracking import TrackingConfig, orbit_grid, simulate_orbits
from .base import Experiment, RunContext, RunOutput
from .common import row_estimator
from .config import ExperimentConfig, label, option

__all__ = ["OwnBodyConfig", "OwnBodyExperiment", "OWN_BODY_ROWS"]

#: The rows: what a user fits to their own arcs.
OWN_BODY_ROWS = ("sh-auto", "network-best", "sh8")


@dataclass(frozen=True)
class OwnBodyConfig(ExperimentConfig):
    """The user's body (a contact binary written as ICQ in km), constants and tracking."""

    length_m: float = option(560.0, "Overall length of the contact binary [m].", above=0)
    head_ratio: float = option(
        0.7, "Head lobe size relative to the main lobe.", at_least=0.2, at_most=1
    )
    density_kg_m3: float = option(
        1900.0, "Bulk density [kg/m^3] behind the GM of the TOML.", above=0
    )
    spin_period_s: float = option(43_200.0, "Spin period [s].", above=0)
    pole_deg: tuple[float, ...] = option(
        (95.0, -67.0), "Pole right ascension and declination in the ICRF [deg]."
    )
    icq_q: int = option(24, "ICQ resolution Q (6 Q^2 + 2 vertices).", at_least=2, at_most=128)
    interior: str = option(
        "uniform",
        "Truth interior (simulator only). Uniform: its centre of mass is the shape's "
        "constant-density centroid, which the user can compute and gives as the frame origin "
        "(other interiors put it elsewhere, and tracking relative to it then needs the centre "
        "of mass from orbit determination).",
    )
    n_mascons: int = option(400, "Truth mascons (simulator only).", at_least=10, at_most=5000)
    orbits: int = option(16, "Orbits on a radius x inclination grid.", at_least=1, at_most=200)
    radius_rb: tuple[float, ...] = option((1.2, 2.0), "Orbit radius range [R_B].", above=1)
    arcs_per_orbit: int = option(7, "Arcs per orbit (40 samples at 14 s).", at_least=1)
    window_spin_periods: float = option(1.0, "Tracking window [spin periods].", above=0)
    sigma_r_m: float = option(0.05, "Position noise per component [m].", above=0)
    max_degree: int = option(10, "Highest SH degree sh-auto considers.", at_least=2, at_most=16)
    folds: int = option(5, "Cross-validation folds of sh-auto.", at_least=2, at_most=20)
    rows: tuple[str, ...] = option(OWN_BODY_ROWS, "Rows to fit.", nonempty=True)

    memory_fix = "lower --orbits, --arcs-per-orbit or --max-degree"

    def memory_parts(self) -> dict[str, float]:
        """Its arcs and its largest fit's arrays [bytes] (network-best's network or the SH
        expansion of the highest degree)."""
        from ..sizing import fit_bytes, network_parameters

        hidden = DEFAULT_HIDDEN  # network-best's network
        sh = SphericalHarmonics(self.max_degree, 1.0).n_params
        n_params = max(sh, network_parameters(hidden))
        samples = TrackingConfig().samples_per_arc
        return fit_bytes(self.orbits * self.arcs_per_orbit, samples, n_params)

    def check(self) -> None:
        if len(self.pole_deg) != 2 or not -90 <= self.pole_deg[1] <= 90:
            raise InputError(f"{label('pole_deg')} must be (ra, dec) with dec in [-90, 90]")
        if len(self.radius_rb) != 2 or self.radius_rb[0] > self.radius_rb[1]:
            raise InputError(f"{label('radius_rb')} must be a range (low, high)")
        unknown = [r for r in self.rows if r not in OWN_BODY_ROWS]
        if unknown:
            raise InputError(
                f"{label('rows')}: unknown {', '.join(unknown)}; known: {', '.join(OWN_BODY_ROWS)}"
            )


def write_user_files(config: OwnBodyConfig, folder: Path) -> Path:
    """The user's files in ``folder``: ``shape.icq`` (km) and ``body.toml``; returns the TOML.
    GM is given to 4 significant digits, as published constants are."""
    shape = folder / "shape.icq"

    def radius(directions):
        return contact_binary_radius(
            directions, length_m=config.length_m, head_ratio=config.head_ratio
        )

    write_icq(shape, radius, q=config.icq_q, units="km")
    volume = float(read_shape(shape, units="km").volume)
    gm = float(f"{G_SI * config.density_kg_m3 * volume:.4g}")
    toml = folder / "body.toml"
    toml.write_text(
        "\n".join(
            [
                'name = "rock"',
                'shape = "shape.icq"',
                'units = "km"',
                f"gm_m3_s2 = {gm!r}",
                f"spin_period_s = {float(config.spin_period_s)!r}",
                "naif_id = 2999001",
                'description = "a contact binary written as ICQ in km"',
                "[rotation]",
                f"pole_ra_deg = {float(config.pole_deg[0])!r}",
                f"pole_dec_deg = {float(config.pole_deg[1])!r}",
                "prime_meridian_deg = 0.0",
                "",
            ]
        )
    )
    return toml


def row_settings(row: str, config: OwnBodyConfig) -> dict:
    """Estimator settings of a row (see :data:`OWN_BODY_ROWS`)."""
    if row == "sh-auto":
        return {
            "term": "sh",
            "degree": tuple(range(2, config.max_degree + 1)),
            "kaula": "cv",
            "folds": config.folds,
        }
    if row == "network-best":
        return preset("network-best")
    return {"term": "sh", "degree": 8}


class OwnBodyExperiment(Experiment):
    """See the module docstring."""

    name = "own-body"
    title = "Own body, own tracking, no truth: ICQ shape in km, body TOML, SPK, truth-free fits"
    config_type = OwnBodyConfig
    aggregate_keys = ("field_error", "export_error")
    default_output = "results/own-body"

    def run(self, config: OwnBodyConfig, ctx: RunContext) -> RunOutput:
        seed, say = ctx.seed, ctx.say
        with tempfile.TemporaryDirectory(prefix="hamgrav-own-body-") as scratch:
            folder = Path(scratch)
            body = read_body_toml(write_user_files(config, folder))
            truth = build_truth(body, config.interior, n_mascons=config.n_mascons, seed=seed)
            families = orbit_grid(config.orbits, tuple(config.radius_rb), (10.0, 80.0))
            tracking = TrackingConfig(
                arcs_per_orbit=config.arcs_per_orbit,
                window_spin_periods=config.window_spin_periods,
                sigma_r_m=config.sigma_r_m,
            )
            simulated = simulate_orbits(truth, families, tracking, seed=seed)
            units = truth.body.units
            kernel = write_spk(simulated, folder / "track.bsp", truth.body)
            # the user's import: the body from its TOML, the noise as the mission states it,
            # and the frame origin where the user puts the centre of mass the SPK's states are
            # relative to: the shape's constant-density centroid (hamgrav body prints it)
            centroid = tuple(float(v) for v in body.mesh_m.center_mass)
            arcs = import_spk(
                [kernel],
                body,
                "all",
                sigma_r_m=simulated.sigma_r_m,
                sigma_v_m_s=simulated.sigma_v_m_s,
                origin_m=centroid,
            )
            # the states stay relative to the truth's centre of mass: the user's frame is that
            # frame with the shape placed at the centroid, a fraction of a metre off
            offset_m = np.asarray(centroid) - np.asarray(truth.body.origin_m)
            say(
                f"{arcs.n_arcs} arcs imported from the SPK (no truth); the centroid is "
                f"{np.linalg.norm(offset_m):.3f} m from the truth's centre of mass"
            )
            # scored where the data are: at the same coordinates as the truth's
            sets = evaluation_sets(truth.body, (1.05, 1.2, 1.5), (30.0,), seed=seed)
            length, potential = units.length_m, units.potential_m2_s2
            truth_v = {  # the truth's perturbing potential [m^2/s^2]
                k: potential * (mascon_potential(truth.mascons, p) - 1 / np.linalg.norm(p, axis=1))
                for k, p in sets.items()
            }
            fits, field_error, export_error, exports = {}, {}, {}, {}
            for row in config.rows:
                start = time.perf_counter()
                est = row_estimator(
                    row_settings(row, config),
                    seed=seed,
                    mapper=ctx.mapper,
                    client=ctx.fit_client,
                    committed=False,
                )
                est.fit(arcs)
                fitted = est.fitted_
                fits[row] = {
                    **{k: fitted.solver.get(k) for k in ("outcome", "iterations", "n_params")},
                    "wall_s": round(time.perf_counter() - start, 1),
                    "degree": getattr(fitted.model.learnable, "degree", None),
                    "chosen": {
                        sel["name"]: sel["chosen"] for sel in fitted.solver.get("selection", [])
                    },
                    "relative_cost": est.diagnostics_.get("relative_cost"),
                    "improved": bool(est.diagnostics_.get("improved")),
                    "overfit": bool(est.diagnostics_.get("overfit")),
                }
                gm = fitted.gm_m3_s2
                field_error[row] = {}
                for k, p in sets.items():
                    points_m = p * length
                    model_v = fitted.potential(points_m) - gm / np.linalg.norm(points_m, axis=1)
                    field_error[row][k] = round(relative_field_error(model_v, truth_v[k]), 4)
                term = fitted.model.learnable
                degree = getattr(term, "degree", 8)
                export = sh_export(
                    fitted,
                    degree=degree,
                    # as export does: a network is projected at its recorded body's R_B
                    reference_radius=None
                    if hasattr(term, "degree")
                    else body_for_model(fitted).brillouin_radius,
                )
                path = write_icgem(export, folder / f"{row}.gfc", source=f"own-body {row}")
                exports[row] = path.read_text().count("\ngfc ")
                export_error[row] = {}
                for k, p in sets.items():
                    if not k.startswith("r"):
                        continue  # an SH series is not valid inside the Brillouin sphere
                    points_m = p * length
                    v = sh_potential(
                        export.c, export.s, export.reference_radius_m, points_m, export.gm_m3_s2
                    ) - export.gm_m3_s2 / np.linalg.norm(points_m, axis=1)
                    export_error[row][k] = round(relative_field_error(v, truth_v[k]), 4)
                say(
                    f"{row}: {fits[row]['outcome']}, field error "
                    + ", ".join(f"{k} {v:.3f}" for k, v in field_error[row].items())
                )
        result = {
            "centroid_offset_m": round(float(np.linalg.norm(offset_m)), 4),
            "body": {
                "name": body.name,
                "gm_m3_s2": body.gm_m3_s2,
                "mesh_vertices": int(len(body.mesh_m.vertices)),
                "brillouin_radius_m": round(truth.body.brillouin_radius_m, 3),
            },
            "n_arcs": arcs.n_arcs,
            "fits": fits,
            "field_error": field_error,
            "export_error": export_error,
            "icgem_coefficient_lines": exports,
        }
        return RunOutput(result)

    def readme(self, report: dict) -> list[str]:
        return own_body_readme(report)

    def figures(self, report: dict, artefacts: dict) -> dict:
        return {}

"""Body reports: the numbers ``hamgrav body`` prints, in physical units where they have one."""

from __future__ import annotations

import numpy as np

from ..core.fields import perturbation_ratio, relative_field_error, shell_points
from ..core.mascons import mascon_potential
from .catalogue import G_SI, Body
from .interiors import DEFAULT_TRUTH_MASCONS, build_truth
from .polyhedron import polyhedron_potential

__all__ = ["body_report", "PERTURBATION_SHELLS_RB"]

PERTURBATION_SHELLS_RB = (1.1, 2.0, 3.0)


def body_report(
    body: Body, *, n_mascons: int = DEFAULT_TRUTH_MASCONS, seed: int = 0, n_directions: int = 500
) -> dict:
    """Physical constants, Brillouin radius, envelope and perturbation figures of ``body``.

    The perturbation ratios (median |a_perturbing| / |a_central| on shells r / R_B) and the
    polyhedron check use the uniform-density truth with ``n_mascons`` mascons.
    """
    truth = build_truth(body, "uniform", n_mascons=n_mascons, seed=seed)
    framed = truth.body
    r_b = framed.brillouin_radius
    ratios = {
        f"{s:.1f}": perturbation_ratio(truth.mascons, shell_points(s * r_b, n_directions, seed))
        for s in PERTURBATION_SHELLS_RB
    }
    pts = shell_points(1.05 * r_b, n_directions, seed)
    v_poly = polyhedron_potential(framed, pts)
    v_masc = mascon_potential(truth.mascons, pts)
    central = 1.0 / np.linalg.norm(pts, axis=1)
    return {
        "name": body.name,
        "description": body.description,
        "gm_m3_s2": body.gm_m3_s2,
        "spin_period_s": body.spin_period_s,
        "synchronous_radius_m": body.units.length_m,
        "brillouin_radius_m": framed.brillouin_radius_m,
        "brillouin_radius_canonical": r_b,
        "volume_m3": float(body.mesh_m.volume),
        "bulk_density_kg_m3": body.gm_m3_s2 / (G_SI * float(body.mesh_m.volume)),
        # where the centre of mass lies at constant density, in the shape file's frame [m]:
        # the --origin of tracking relative to the centre of mass of a shape whose own
        # origin is elsewhere
        "constant_density_centre_m": [float(v) for v in body.mesh_m.center_mass],
        "mesh_vertices": int(len(body.mesh_m.vertices)),
        "mesh_faces": int(len(body.mesh_m.faces)),
        "envelope_fraction_inside_brillouin": framed.envelope_fraction_inside_brillouin(),
        "perturbation_ratio": ratios,
        "truth_mascons": len(truth.mascons),
        "uniform_truth_vs_polyhedron_r1.05": {
            "total_potential_rel_error": relative_field_error(v_masc, v_poly),
            "perturbing_potential_rel_error": relative_field_error(
                v_masc - central, v_poly - central
            ),
        },
    }

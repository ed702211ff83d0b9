"""The own-body experiment's README, from results.json."""

from __future__ import annotations

from .tables import range_row

__all__ = ["own_body_readme"]


def own_body_readme(report: dict) -> list[str]:
    """README lines of an own-body report."""
    first = report["repetitions"][0]
    agg = report["aggregate"]
    n = len(report["repetitions"])
    field, export = agg["field_error"], agg["export_error"]
    sets = list(next(iter(field.values())))
    shells = list(next(iter(export.values())))
    lines = [
        f"A body of {first['body']['mesh_vertices']} vertices read from an ICQ file in km and a "
        f"body TOML (GM {first['body']['gm_m3_s2']:.4g} m^3/s^2), {first['n_arcs']} arcs "
        "imported from a type-13 SPK without a truth; every row chooses its model from the "
        "arcs alone. Relative errors of the perturbing potential against the simulator's truth "
        f"(1 = no correction), median (min-max) over {n} draws.",
        "",
        "## The fitted field in SI (FittedModel.potential at points in metres)",
        "",
        "| row | " + " | ".join(sets) + " | beats no correction everywhere |",
        "|---|" + "---|" * (len(sets) + 1),
    ]
    for row, errors in field.items():
        worst = max(errors[s]["max"] for s in sets)
        verdict = f"{'yes' if worst < 1 else 'no'} (worst {worst:.3f})"
        lines.append(range_row([row], errors, sets, after=[verdict]))
    lines += [
        "",
        "## The exported ICGEM coefficients, evaluated on their own (shells outside R_B)",
        "",
        "| row | " + " | ".join(shells) + " |",
        "|---|" + "---|" * len(shells),
    ]
    for row, errors in export.items():
        lines.append(range_row([row], errors, shells))
    lines += ["", "## What each fit chose (first draw)", ""]
    for row, f in first["fits"].items():
        chosen = ", ".join(f"{k} {v}" for k, v in f["chosen"].items())
        lines.append(
            f"- {row}: {f['outcome']}, {f['n_params']} parameters, held-out cost "
            f"{f['relative_cost']:.3g} of no correction"
            + (", flagged overfit" if f.get("overfit") else "")
            + ("" if f["improved"] else ", flagged as no improvement")
            + (f", chosen by cross-validation: {chosen}" if chosen else "")
            + f" ({f['wall_s']:.0f} s)"
        )
    return lines

"""The selection experiment's README, from results.json."""

from __future__ import annotations

from .paper import STATEMENT_COLUMNS, Claim, claims_table
from .tables import range_row

__all__ = ["selection_readme"]


def selection_readme(report: dict, truth_shell: float, within: float) -> list[str]:
    """README lines of a selection report."""
    reps = report["repetitions"]
    first, n = reps[0], len(reps)
    agg = report["aggregate"]["field_error"]
    sets = list(next(iter(agg.values())))
    shells = [s for s in sets if s.startswith("r")]
    lines = [
        f"{first['n_arcs']} arcs of {first['body']} ({first['interior']}), {n} draws. Relative "
        "errors of the perturbing potential (1 = no correction), median (min-max); 'worst "
        "shell' is the largest error on any shell in any draw. Rows ending in -cv choose "
        "from the arcs alone (k-fold cross-validation, one-standard-error rule); -truth rows "
        f"choose with the truth (the {truth_shell:g} R_B shell): experiments only.",
        "",
        "| row | " + " | ".join(sets) + " | worst shell |",
        "|---|" + "---|" * (len(sets) + 1),
    ]
    for row, errors in agg.items():
        worst = max(errors[s]["max"] for s in shells)
        lines.append(range_row([row], errors, sets, after=[f"{worst:.3f}"]))
    cv_rows = [r for r in agg if r.startswith("sh") and (r.endswith("-cv") or r == "sh-auto")]
    worst_cv = {r: max(agg[r][s]["max"] for s in shells) for r in cv_rows}
    claims = []
    if worst_cv:
        claims.append(
            Claim(
                "SH with a cross-validated alpha or degree never worse than no correction on "
                "the shells",
                ours=f"worst {max(worst_cv.values()):.3f} ({max(worst_cv, key=worst_cv.get)})",
                verdict="yes" if max(worst_cv.values()) < 1 else "no",
            )
        )
    weights = [r["network_weight"] for r in reps if r["network_weight"]]
    if weights:
        hits = sum(w["within"] for w in weights)
        ratios = sorted(w["cv_over_truth"] for w in weights)
        claims.append(
            Claim(
                f"network-best's cross-validated weight within {within:.0%} of the "
                f"truth-chosen weight's {truth_shell:g} R_B error in 7 of 8",
                ours=f"{hits} of {len(weights)} (ratio {ratios[len(ratios) // 2]:.3f}, worst "
                f"{ratios[-1]:.3f})",
                verdict="yes" if hits >= round(7 / 8 * len(weights)) else "no",
            )
        )
        lowest = [w for w in weights if "lowest_within" in w]
        if len(lowest) == len(weights):
            hits = sum(w["lowest_within"] for w in lowest)
            ratios = sorted(w["lowest_over_truth"] for w in lowest)
            claims.append(
                Claim(
                    "(for comparison: the weight of lowest held-out cost, the 'lowest' rule "
                    "on the same folds)",
                    ours=f"{hits} of {len(lowest)} (ratio {ratios[len(ratios) // 2]:.3f}, "
                    f"worst {ratios[-1]:.3f})",
                    verdict="-",
                )
            )
    lines += ["", "## The issue's statements", "", *claims_table(claims, STATEMENT_COLUMNS)]
    choosing = [row for row, c in first["chosen"].items() if c]
    lines += ["", "## What each draw chose", "", "| seed | " + " | ".join(choosing) + " |"]
    lines.append("|---|" + "---|" * len(choosing))
    for seed, rep in zip(report["seeds"], reps, strict=True):
        cells = [", ".join(f"{k} {v:g}" for k, v in rep["chosen"][row].items()) for row in choosing]
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    return lines

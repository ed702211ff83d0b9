"""README and figures of the deep-region experiment (:mod:`hamgrav.experiments.deep`): the
aggregate next to the paper's numbers, the stage-by-stage exterior error, the geometry, the
error by radial bin and the equatorial maps, the bins before and after the descents, and the
exterior error against the number of orbits for the arrival orders and the D-optimal
campaign."""

from __future__ import annotations

import re

import matplotlib
import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from .figures import orbits_and_radii_figure
from .paper import TARGET_COLUMNS, Claim, claims_table, count_applicable, count_draws
from .tables import format_range

__all__ = [
    "deep_readme",
    "geometry_figure",
    "bins_figure",
    "maps_figure",
    "descents_figure",
    "orders_figure",
]


def _sh_rows(models) -> list[str]:
    """The SH rows among ``models``, by degree."""
    return sorted((m for m in models if re.fullmatch(r"sh\d+", m)), key=lambda m: int(m[2:]))


def _network_row(models) -> str:
    """The network row among ``models`` (the one row that is not SH)."""
    return next(m for m in models if not re.fullmatch(r"sh\d+", m))


def _cell(summary: dict, model: str, key: str, fmt: str = "{:.3g}") -> str:
    return format_range(summary.get(model, {}).get(key), fmt)


def _le(value, bound) -> bool:
    return value is not None and value <= bound


def _gt(value, bound) -> bool:
    return value is not None and value > bound


def deep_readme(report: dict, paper: dict) -> list[str]:
    """README lines of a deep-region report; ``paper``: the paper's numbers
    (:data:`hamgrav.experiments.deep.PAPER`)."""
    reps = report["repetitions"]
    cfg = report["config"]
    first = reps[0]
    summary = report["aggregate"]["summary"]
    bins_agg = report["aggregate"]["deep_bins"]
    models = list(first["summary"])
    sh, net = _sh_rows(models), _network_row(models)
    labels = list(first["deep_bin_points"])
    # the deepest bin is the first that holds points (the summary's "deepest_bin")
    deepest = next((k for k, n in first["deep_bin_points"].items() if n), labels[0])
    shells = ", ".join(f"{s:g}" for s in cfg["shells_rb"])
    lines = [
        f"{first['n_arcs']} arcs of {cfg['body']} ({cfg['interior']} interior, "
        f"{cfg['n_mascons']} truth mascons): {cfg['orbits']} orbits on a grid of start radii "
        f"{cfg['radius_rb'][0]:g}-{cfg['radius_rb'][1]:g} R_B x inclinations "
        f"{cfg['inclination_deg'][0]:g}-{cfg['inclination_deg'][1]:g} deg, "
        f"{cfg['arcs_per_orbit']} arcs of 40 samples at 14 s each; orbits dipping below "
        f"{cfg['min_radius_rb']:g} R_B are redrawn. The orbits arrive in "
        f"{len(first['stages'])} stages in a fixed order (orbits by stage: "
        + "; ".join(",".join(map(str, s["orbits"])) for s in first["stages"])
        + "); every model is fitted on the identical arcs, each stage warm-started from the "
        f"previous one: SH of degree {', '.join(m[2:] for m in sh)} (LM) and `{net}` (the "
        f"network-best configuration, hidden layers {','.join(map(str, cfg['hidden']))}"
        + (
            f", its envelope softened at r_c = {cfg['envelope_softening_rb']:g} R_B "
            "(R_w^3 / (r^2 + r_c^2)^(3/2) for (R_w / r)^3)"
            if cfg.get("envelope_softening_rb")
            else ""
        )
        + (
            f", with the harmonic penalty of weight {cfg['harmonic']:g}: its Laplacian, scaled "
            "by (r / R_w)^5, pushed to zero at 1500 points outside the body"
            if cfg.get("harmonic")
            else ""
        )
        + ")"
        + (
            ", every model on the imaged shape at constant density (the known part, as "
            "mascons; the truth's interior may differ from it), fitting what it leaves"
            + (
                " (the shape left where it is, with the point dipole that takes the offset of "
                "its centre of mass out of the known part: --prior-placement in-place)"
                if cfg.get("prior_placement") == "in-place"
                else ""
            )
            if cfg.get("prior") == "shape"
            else ""
        )
        + ". "
        "Errors are relative errors of the perturbing potential (1 = no correction): "
        f"`exterior` is the mean over the shells {shells} R_B, `deep` the "
        f"{cfg['altitude_m']:g} m surface-following set inside the Brillouin sphere "
        "(r < R_B), and the bins split that set by r / R_B.",
        "",
        "Tracked samples, r / R_B:",
        "",
        "| seed | samples | min | q1 | median | q3 | max | below 0.96 R_B |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in reps:
        q = r["radius_rb"]
        lines.append(
            f"| {r['seed']} | {q['n_samples']} | {q['min']:.3f} | {q['q1']:.3f} | "
            f"{q['median']:.3f} | {q['q3']:.3f} | {q['max']:.3f} | {q['below_floor']} |"
        )
    lines += ["", "## Against the paper", ""]
    lines += _paper_rows(reps, summary, sh, net, deepest, cfg["altitude_m"], paper)
    lines += [
        "",
        "## Final models",
        "",
        "| model | exterior | deep | " + " | ".join(labels) + " | patch median |",
        "|---|---|---|" + "---|" * len(labels) + "---|",
    ]
    for m in models:
        cells = [_cell(summary, m, "exterior"), _cell(summary, m, "deep")]
        cells += [format_range(bins_agg.get(m, {}).get(k), "{:.3g}") for k in labels]
        cells.append(_cell(summary, m, "patch_median"))
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    prior = report["aggregate"].get("prior_alone", {}).get("shape")
    if prior:  # the floor the models start from: the known shape, no correction
        cells = [_cell({"shape": prior}, "shape", k) for k in ("exterior", "deep", *labels)]
        lines.append("| the shape prior alone | " + " | ".join(cells) + " | - |")
    lines += [
        "",
        "Points of the surface-following set per bin: "
        + ", ".join(f"{k} {n}" for k, n in first["deep_bin_points"].items())
        + ". Patches: the points of the equatorial map (outside the body) where SH "
        + " or SH ".join(str(d) for d in cfg["map_degrees"])
        + " is worse than no correction, "
        + ", ".join(
            f"{r['patch_points']} points"
            + (
                ""
                if r["patch_inside_brillouin"] is None
                else f" ({100 * r['patch_inside_brillouin']:.0f} % inside R_B)"
            )
            for r in reps
        )
        + " per repetition; the map error is pointwise, |V_model - V_true| / |V_true|, "
        "so it is large for every model where the true perturbing potential changes sign.",
        "",
        "Exterior error by stage (first repetition):",
        "",
        "| stage | arcs | " + " | ".join(models) + " |",
        "|---|---|" + "---|" * len(models),
    ]
    for k, st in enumerate(first["stages"]):
        cells = [format_range(_one(st["exterior_error"].get(m)), "{:.3g}") for m in models]
        lines.append(f"| {k + 1} | {st['n_arcs']} | " + " | ".join(cells) + " |")
    lines += ["", "Fits of the last stage (first repetition):", ""]
    for m in models:
        f = first["fits"][m]
        lines.append(
            f"- {m}: {f['solver']}, {f['outcome']}, {f['iterations']} iterations, "
            f"{f['wall_s']:.1f} s"
        )
    lines += _descents_section(report, net)
    lines += _orders_section(report)
    lines += [
        "",
        "Known differences of set-up (the paper does not fix them): the truth is "
        f"{cfg['n_mascons']} k-means mascons of the shape; the orbit grid, the redraw floor "
        "and the stage order are ours. The paper quotes one run; seeds change the truth's "
        "mascons, the orbits' node and phase, and the noise.",
        "",
        "Wall time per repetition [s]: " + ", ".join(f"{r['wall_s']:.0f}" for r in reps),
    ]
    parts = [list(r.get("wall_parts_s", {})) for r in reps]
    if parts and parts[0]:
        lines += [
            "",
            "Wall time by part [s] (random orders and D-optimal: the sum of their work "
            "units; `orders_elapsed`: the time they took together):",
            "",
            "| seed | " + " | ".join(parts[0]) + " |",
            "|---|" + "---|" * len(parts[0]),
        ]
        for r in reps:
            w = r.get("wall_parts_s", {})
            lines.append(
                f"| {r['seed']} | " + " | ".join(f"{w.get(k, 0):.0f}" for k in parts[0]) + " |"
            )
    return lines


def _one(value) -> dict | None:
    """A single value as a one-repetition summary (for :func:`format_range`)."""
    if value is None:
        return None
    return {"median": value, "min": value, "max": value, "n": 1}


def _paper_rows(reps, summary, sh, net, deepest, altitude, paper) -> list[str]:
    """The paper's numbers (300 m above the surface) beside ours at ``altitude`` [m] (median,
    min-max over the repetitions)."""
    deep = paper["deep"]
    sh_deep = [d for d in deep if d in sh]
    bound = paper["network_deepest_bin"]
    claims = [
        Claim(
            "SH 8 exterior error, shells 1.2-1.7 R_B",
            f"{paper['sh8_exterior']}",
            _cell(summary, "sh8", "exterior"),
        ),
        Claim(
            "SH " + " / ".join(d[2:] for d in deep) + f", {altitude:g} m set inside R_B",
            " / ".join(f"{v:g}" for v in deep.values()),
            " / ".join(_cell(summary, d, "deep") for d in deep),
        ),
        Claim(
            f"SH 8 at {altitude:g} m worse than no correction",
            f"{deep['sh8']}",
            _cell(summary, "sh8", "deep"),
            "> 1",
            count_draws(_gt(r["summary"]["sh8"]["deep"], 1.0) for r in reps)
            if "sh8" in sh
            else "-",
        ),
        Claim(
            f"network, deepest bin ({deepest})",
            f"{bound}",
            _cell(summary, net, "deepest_bin"),
            f"<= {bound}",
            count_draws(_le(r["summary"][net]["deepest_bin"], bound) for r in reps),
        ),
        Claim(
            "network, worst bin", f"{paper['network_worst_bin']}", _cell(summary, net, "worst_bin")
        ),
        Claim(
            "patch median, SH 8 / 12",
            f"{paper['patch_median_sh']}",
            " / ".join(_cell(summary, m, "patch_median") for m in ("sh8", "sh12")),
        ),
        Claim(
            "patch median, network",
            f"{paper['patch_median_network']}",
            _cell(summary, net, "patch_median"),
        ),
        *_later_claims(reps, net, deepest, paper),
    ]
    rows = claims_table(claims, TARGET_COLUMNS)
    if len(sh_deep) < len(deep):
        rows.append("")
        rows.append("(-: a degree the paper quotes was not fitted in this run.)")
    return rows


def _orders_value(rep: dict, curve: str, n: int):
    """A repetition's value of ``curve`` after ``n`` orbits (None when not run)."""
    return rep.get("orders_summary", {}).get(curve, {}).get(f"{n} orbits")


def _d_optimal_below(rep: dict, from_orbits: int) -> bool | None:
    """Whether the D-optimal curve lies below every random order at every stage with at
    least ``from_orbits`` orbits (None: no such stage, or a curve is missing)."""
    orders = rep.get("orders", {})
    dopt, random = orders.get("d-optimal"), orders.get("random")
    stages = [k for k, n in enumerate(orders.get("n_orbits", [])) if n >= from_orbits]
    if not dopt or not random or not stages:
        return None
    for k in stages:
        values = [curve[k] for curve in random]
        if dopt[k] is None or any(v is None for v in values) or dopt[k] >= min(values):
            return False
    return True


def _first_picks_polar(rep: dict, top_inclination: float) -> bool | None:
    """Whether the D-optimal first stage is at ``top_inclination`` [deg] (the grid's
    highest), each pick at a different start radius: the paper's "three 80-degree orbits
    across the radius range"."""
    picks = rep.get("d_optimal_first_picks")
    if not picks:
        return None
    radii = {round(p[0], 6) for p in picks}
    return all(p[1] == top_inclination for p in picks) and len(radii) == len(picks)


def _later_claims(reps, net, deepest, paper) -> list[Claim]:
    """The paper's statements of the descent assimilation, the arrival orders and the
    D-optimal campaign beside ours (median, min-max over the repetitions)."""
    claims = []
    after, before = paper["after_descents"], paper["deep"]
    if any("descents_summary" in r for r in reps):
        d_agg = _aggregate_of(reps, "descents_summary")
        bound = after["network_deepest_bin"]
        claims += [
            Claim(
                f"network, deepest bin ({deepest}) after the descents",
                f"{bound}",
                _cell(d_agg, net, "deepest_bin_after"),
                f"<= {bound}",
                count_draws(
                    _le(r.get("descents_summary", {}).get(net, {}).get("deepest_bin_after"), bound)
                    for r in reps
                ),
            ),
            Claim(
                "SH 8 / 12 after the descents, deep set (before)",
                f"{after['sh8']:g} / {after['sh12']:g} ({before['sh8']:g} / {before['sh12']:g})",
                " / ".join(
                    f"{_cell(d_agg, m, 'deep_after')} ({_cell(d_agg, m, 'deep_before')})"
                    for m in ("sh8", "sh12")
                ),
            ),
        ]
    if any(r.get("orders", {}).get("random") for r in reps):
        lo6, hi6 = paper["random_after_6"]
        lo18, hi18 = paper["random_after_18"]
        claims += [
            Claim(
                "random orders after 6 orbits, luckiest / unluckiest",
                f"{lo6} / {hi6}",
                " / ".join(_order_cell(reps, c, 6) for c in ("random-best", "random-worst")),
            ),
            Claim(
                "random orders after 18 orbits, luckiest / unluckiest",
                f"{lo18}-{hi18}",
                " / ".join(_order_cell(reps, c, 18) for c in ("random-best", "random-worst")),
            ),
        ]
    if any("d-optimal" in r.get("orders", {}) for r in reps):
        d15, from_n = paper["d_optimal_15"], paper["d_optimal_below_from"]
        top = max(
            p["inclination_deg"] for r in reps for stage in r["d_optimal_picks"] for p in stage
        )
        after_15 = [_orders_value(r, "d-optimal", 15) for r in reps]
        claims += [
            Claim(
                "D-optimal after 15 orbits",
                f"{d15}",
                _order_cell(reps, "d-optimal", 15),
                f"<= {d15}",
                count_applicable(None if v is None else _le(v, d15) for v in after_15),
            ),
            Claim(
                f"D-optimal below every random order from {from_n} orbits on",
                "yes",
                "",
                "yes",
                count_applicable(_d_optimal_below(r, from_n) for r in reps),
            ),
            Claim(
                f"D-optimal first picks: {top:g} deg, each at another start radius",
                "80 deg x 3 radii",
                "; ".join(
                    ", ".join(f"{p[0]:g}/{p[1]:g}" for p in r.get("d_optimal_first_picks", []))
                    for r in reps
                )
                + " (R_B/deg)",
                "",
                count_applicable(_first_picks_polar(r, top) for r in reps),
            ),
        ]
    return claims


def _aggregate_of(reps: list[dict], key: str) -> dict:
    """:func:`~hamgrav.experiments.runner.aggregate` of one key (its ``{model: {stat}}``)."""
    from .tables import aggregate

    return aggregate(reps, (key,))[key]


def _order_cell(reps: list[dict], curve: str, n: int) -> str:
    """``curve`` after ``n`` orbits: median (min-max) over the repetitions, "-" if absent."""
    return _cell(_aggregate_of(reps, "orders_summary"), curve, f"{n} orbits")


def _descents_section(report: dict, net: str) -> list[str]:
    """The descent assimilation: the descents, and each refitted model's bins before and
    after."""
    reps = report["repetitions"]
    first = reps[0]
    if "descents" not in first:
        return []
    d = first["descents"]
    labels = list(first["deep_bin_points"])
    agg_before = report["aggregate"]["deep_bins"]
    agg_after = report["aggregate"].get("deep_bins_after_descents", {})
    d_agg = report["aggregate"].get("descents_summary", {})
    cfg = report["config"]
    if cfg.get("descent_span", "end") == "whole":
        tracked = "40 samples spread evenly from release to contact"
    else:
        tracked = "40 samples at 14 s ending at contact"
    iterations = cfg.get("descent_iterations", 0)
    held = cfg.get("descent_validation", 0.0)
    if iterations and held:
        refit = (
            f"{round(held * d['n'])} of the descents (seeded) held out of every refit, the rest "
            f"trained; the network runs {iterations} LM iterations per member with no patience "
            "or gate and returns the iterate, the stage-6 fit included, with the lowest cost on "
            "the held-out descents, SH its own solver; the earlier hold-outs stay untrained"
        )
    elif iterations:
        refit = (
            "every descent trained, with no validation stop; the earlier hold-outs stay "
            f"untrained; the network runs {iterations} LM iterations per member, SH its own "
            "solver"
        )
    else:
        refit = (
            "the network holds out its usual share of the arriving arcs for validation: one descent"
        )
    share = cfg.get("descent_share", 0.0)
    if share:
        refit += (
            f"; the descent arcs weigh as a set {share:g} of the cost, the orbital arcs "
            f"{1 - share:g}, each measured by what no correction leaves on it"
        )
    anchor = cfg.get("descent_anchor", 0.0)
    on = cfg.get("descent_anchor_on", "acceleration")
    if anchor:
        refit += (
            f"; the network's refit holds its learned "
            f"{'field' if on == 'acceleration' else on} near the stage-6 fit's, with "
            f"the weight {anchor:g}, at the collocation points farther than "
            f"{cfg['descent_anchor_clearance_rb']:g} R_B from every descent sample "
            "(--descent-anchor)"
        )
    lines = [
        "",
        "## Descent assimilation",
        "",
        f"{d['n']} deployment descents released at 1.3 R_B (at rest in inertial space plus a "
        "1-3 cm/s inward manoeuvre within 20 deg of the centre), flown under the truth to "
        f"contact, each tracked as one arc of {tracked}, with the "
        "orbital arcs' noise. They arrive as a last stage after the six of the fixed order; "
        "the models below are warm-refitted on all arcs from their stage-6 parameters "
        f"({refit}). First repetition: descents of "
        f"{d['duration_s']['min']:.0f}-{d['duration_s']['max']:.0f} s, arcs spanning "
        f"{d['arc_radius_rb']['min']:.2f}-{d['arc_radius_rb']['max']:.2f} R_B, contact at "
        + ", ".join(f"{v:.2f}" for v in d["contact_radius_rb"])
        + " R_B.",
        "",
        "| model | | exterior | deep | " + " | ".join(labels) + " |",
        "|---|---|---|---|" + "---|" * len(labels),
    ]
    agg_control = report["aggregate"].get("deep_bins_descent_control", {})
    for m in d_agg:
        rows = [("before", "before", agg_before), ("after", "after", agg_after)]
        if m in agg_control:
            rows.append(("control", "the same refit, no descents", agg_control))
        for when, row, agg in rows:
            cells = [_cell(d_agg, m, f"exterior_{when}"), _cell(d_agg, m, f"deep_{when}")]
            cells += [format_range(agg.get(m, {}).get(k), "{:.3g}") for k in labels]
            lines.append(f"| {m} | {row} | " + " | ".join(cells) + " |")
    if agg_control:
        lines += [
            "",
            "The control row (--descent-control) runs the network's refit from the same "
            "stage-6 fit with the same solver and budget but no descent arcs: what the refit "
            "alone moves, apart from what the descents bring ("
            + (
                "with --descent-validation it trains on no descent and the held-out descents "
                "choose its iterate)."
                if held
                else "without --descent-iterations it validates on the orbital hold-outs alone, "
                "having no descent to hold out)."
            ),
        ]
    fits = first["descents"].get("fits", {})
    lines += ["", "Refits on the descents (first repetition):", ""]
    for m, f in fits.items():
        line = (
            f"- {m}: {f['n_arcs']} arcs, {f['outcome']}, {f['iterations']} iterations, "
            f"{f['wall_s']:.1f} s"
        )
        if f.get("warm_started") is False:
            line += ", restarted from its initialisation"
        if f.get("relative_cost") is not None:
            line += f", cost on the {f['checked_on']} {f['relative_cost']:.3g} of no correction's"
        if f.get("descent_weight") is not None:
            line += f", each descent arc weighing {f['descent_weight']:.3g}"
        if f.get("best_iterations") and _selects(first, m):
            line += ", iterate returned " + _iterates(f["best_iterations"])
        if f.get("anchor"):
            line += f", anchored at {f['anchor']['points']} points"
        if f.get("control"):
            c = f["control"]
            line += (
                f"; its control (no descents): {c['n_arcs']} arcs, {c['outcome']}, "
                f"{c['iterations']} iterations, {c['wall_s']:.1f} s"
            )
            if c.get("best_iterations"):
                line += ", iterate returned " + _iterates(c["best_iterations"])
            if c.get("anchor"):
                line += f", anchored at {c['anchor']['points']} points"
        lines.append(line)
    chosen = {
        m: [r["descents"]["fits"][m].get("best_iterations") for r in reps if "descents" in r]
        for m in fits
        if _selects(first, m)
    }
    if any(all(v) for v in chosen.values()):
        lines += [
            "",
            "The iterate each refit returned (the lowest cost on the held-out descents; 0 is "
            "the stage-6 fit), by repetition:",
            "",
        ]
        for m, by_rep in chosen.items():
            if all(by_rep):
                lines.append(f"- {m}: " + "; ".join(", ".join(map(str, v)) for v in by_rep))
    agreement = [
        (r["seed"], m, r["descents_summary"][m])
        for r in reps
        for m in r.get("descents_summary", {})
        if "deep_change" in r["descents_summary"][m]
    ]
    if agreement:
        lines += [
            "",
            "What each ensemble's refit did on the deep set, told without the truth (RMS over "
            "the set, relative to the RMS of the perturbing potential before the refit): the "
            "change of the members' mean, and the members' spread (their standard deviation "
            "over sqrt(members)) before -> after; beside it the truth's verdict, the deep-set "
            "error before -> after, by repetition:",
            "",
        ]
        for seed, m, a in agreement:
            f = {k: "n/a" if v is None else f"{v:.3g}" for k, v in a.items()}
            # the acceleration's error: recorded by the runs after it was added
            acceleration = (
                f" (of the acceleration, what the descents observe: "
                f"{f['deep_acceleration_before']} -> "
                f"{f['deep_acceleration_after']})"
                if "deep_acceleration_after" in f
                else ""
            )
            lines.append(
                f"- seed {seed}, {m}: change {f['deep_change']}, spread "
                f"{f['deep_spread_before']} -> {f['deep_spread_after']}; error "
                f"{f['deep_before']} -> {f['deep_after']}{acceleration}"
            )
    with_descents = [r for r in reps if "descents" in r]
    restarts = {
        m: sum(not r["descents"]["fits"][m]["warm_started"] for r in with_descents) for m in fits
    }
    if any(restarts.values()):
        lines += [
            "",
            "A model whose last orbital fit does not propagate the descent arcs (they reach deep "
            "inside the Brillouin sphere, where an SH series diverges) is refitted from its "
            "initialisation on all the arcs instead of warm-started; so it was in "
            + ", ".join(f"{m}: {n} of {len(with_descents)}" for m, n in restarts.items())
            + " repetitions.",
        ]
    return lines


def _orders_section(report: dict) -> list[str]:
    """The arrival orders and the D-optimal campaign: the network's mean exterior error
    after each stage, and what D-optimal picks."""
    reps = report["repetitions"]
    first = reps[0]
    orders = first.get("orders")
    if not orders or (not orders.get("random") and "d-optimal" not in orders):
        return []
    agg = report["aggregate"].get("orders_summary", {})
    curves = [c for c in ("fixed", "random-best", "random-worst", "d-optimal") if c in agg]
    lines = [
        "",
        "## Arrival orders and the D-optimal campaign",
        "",
        f"The network alone (`{_network_row(first['summary'])}`), warm-refitted stage by "
        f"stage on the same {len(orders['n_orbits'])} stages of orbits: the fixed order "
        f"above, {len(orders.get('random', []))} random permutations of the orbits to the "
        "stages (seeded by the repetition's seed), and the D-optimal campaign, which before "
        "each stage picks the stage's orbits greedily from those not yet flown by the "
        "paper's gain (log det of the predicted information, eps = max(1e-8, 1e-6 tr / n_p)) "
        "under the current network; its first stage is chosen under the network's seeded "
        "initialisation, as the paper's accumulated information starts at zero. The "
        "accumulated information is the running sum of the picks' information as predicted "
        "when picked; the ensemble's members are fitted each on its own, so the information "
        "is one block per member (eps per member, gains summed). Mean "
        "exterior error after n orbits (random-best / -worst: the luckiest and unluckiest "
        "of the random orders at that stage):",
        "",
        "| curve | " + " | ".join(str(n) for n in orders["n_orbits"]) + " |",
        "|---|" + "---|" * len(orders["n_orbits"]),
    ]
    for c in curves:
        cells = [format_range(agg[c].get(f"{n} orbits"), "{:.3g}") for n in orders["n_orbits"]]
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    if "d_optimal_picks" in first:
        lines += ["", "D-optimal picks by stage, radius [R_B] / inclination [deg]:", ""]
        for r in reps:
            stages = "; ".join(
                ", ".join(f"{p['radius_rb']:g}/{p['inclination_deg']:g}" for p in stage)
                for stage in r.get("d_optimal_picks", [])
            )
            lines.append(f"- seed {r['seed']}: {stages}")
    return lines


def geometry_figure(report: dict, artefacts: dict) -> Figure:
    """The arcs over the shape and the histogram of the samples' radii (first repetition),
    the deep-region bins shaded."""
    edges = report["config"]["deep_bins_rb"]
    first = report["repetitions"][0]
    return orbits_and_radii_figure(
        artefacts["vertices_m"],
        artefacts["faces"],
        artefacts["brillouin_radius_m"],
        artefacts["arc_positions_m"],
        artefacts["arc_trajectory"],
        shaded_rb=(edges[0], edges[-1]),
        title=f"{first['body']}: {first['n_arcs']} arcs (body frame, seed {first['seed']})",
    )


def bins_figure(report: dict) -> Figure:
    """Error by radial bin per model: the median over the repetitions, min-max shaded."""
    agg = report["aggregate"]["deep_bins"]
    edges = np.asarray(report["config"]["deep_bins_rb"], dtype=float)
    centres = 0.5 * (edges[:-1] + edges[1:])
    fig = Figure(figsize=(6.5, 4.2))
    ax = fig.add_subplot()
    for i, (model, by_bin) in enumerate(agg.items()):
        labels = list(report["repetitions"][0]["deep_bin_points"])
        stats = [by_bin.get(k, {}) for k in labels]
        med = np.array([np.nan if s.get("median") is None else s["median"] for s in stats])
        ax.plot(centres, med, "o-", color=f"C{i}", label=model)
        lo = np.array([np.nan if s.get("min") is None else s["min"] for s in stats])
        hi = np.array([np.nan if s.get("max") is None else s["max"] for s in stats])
        if np.any(hi > lo):
            ax.fill_between(centres, lo, hi, color=f"C{i}", alpha=0.2, lw=0)
    ax.axhline(1.0, color="k", ls=":", lw=1, label="no correction")
    ax.set_yscale("log")
    ax.set_xticks(centres, list(report["repetitions"][0]["deep_bin_points"]), fontsize=8)
    ax.set_xlabel(f"r / R_B, {report['config']['altitude_m']:g} m above the surface")
    ax.set_ylabel("relative field error")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def maps_figure(report: dict, artefacts: dict) -> Figure:
    """Pointwise error maps in the equatorial plane for the SH map degrees and the network,
    one logarithmic colour scale, the body's cross-section masked (first repetition)."""
    maps = artefacts["maps"]
    models = [f"sh{d}" for d in report["config"]["map_degrees"]]
    models.append(_network_row(maps["errors"]))
    axis = maps["axis_m"]
    n = len(axis)
    images = {m: maps["errors"][m].reshape(n, n) for m in models}
    finite = np.concatenate([v[np.isfinite(v) & (v > 0)] for v in images.values()])
    lo = min(float(np.percentile(finite, 1)), 0.1) if finite.size else 1e-3
    hi = max(float(np.percentile(finite, 99)), 10.0) if finite.size else 10.0
    cmap = matplotlib.colormaps["magma_r"].with_extremes(bad="0.6")
    fig = Figure(figsize=(4.2 * len(models), 4.0))
    axes = fig.subplots(1, len(models), squeeze=False)[0]
    extent = (axis[0], axis[-1], axis[0], axis[-1])
    r_b = artefacts["brillouin_radius_m"]
    angle = np.linspace(0, 2 * np.pi, 200)
    for ax, m in zip(axes, models, strict=True):
        masked = np.ma.masked_invalid(images[m])
        image = ax.imshow(
            masked,
            origin="lower",
            extent=extent,
            cmap=cmap,
            norm=LogNorm(vmin=lo, vmax=hi),
        )
        ax.contour(axis, axis, masked, levels=[1.0], colors="w", linewidths=0.6)
        ax.plot(r_b * np.cos(angle), r_b * np.sin(angle), "k--", lw=0.8)
        ax.set_title(m)
        ax.set_xlabel("x [m]")
        ax.set_aspect("equal")
    axes[0].set_ylabel("y [m]")
    fig.colorbar(image, ax=list(axes), shrink=0.8, label="|V_model - V_true| / |V_true|")
    return fig


def descents_figure(report: dict, artefacts: dict) -> Figure:
    """(a) The descent arcs over the shape's vertices, x-y projection [m] (first repetition);
    (b) error by radial bin of the refitted models before (dashed) and after (solid) the
    descents: the median over the repetitions, min-max shaded after."""
    fig = Figure(figsize=(11, 4.4))
    ax0, ax = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1, 1.3]})
    vertices = artefacts["vertices_m"]
    ax0.scatter(vertices[:, 0], vertices[:, 1], s=0.3, color="0.75", rasterized=True)
    for k, path in enumerate(artefacts.get("descent_positions_m", [])):
        ax0.plot(path[:, 0], path[:, 1], "-", color=f"C{k % 10}", lw=1.5)
        ax0.plot(path[-1, 0], path[-1, 1], "x", color=f"C{k % 10}")
    angle = np.linspace(0, 2 * np.pi, 200)
    r_b = artefacts["brillouin_radius_m"]
    ax0.plot(r_b * np.cos(angle), r_b * np.sin(angle), "k--", lw=0.8)
    ax0.set_aspect("equal")
    ax0.set_xlabel("x [m]")
    ax0.set_ylabel("y [m]")
    ax0.set_title("(a) descent arcs (x: contact)", fontsize=9)
    labels = list(report["repetitions"][0]["deep_bin_points"])
    edges = np.asarray(report["config"]["deep_bins_rb"], dtype=float)
    centres = 0.5 * (edges[:-1] + edges[1:])
    after = report["aggregate"]["deep_bins_after_descents"]
    before = report["aggregate"]["deep_bins"]

    def column(agg, model, stat):
        stats = [agg.get(model, {}).get(k, {}) for k in labels]
        return np.array([np.nan if s.get(stat) is None else s[stat] for s in stats])

    for i, model in enumerate(after):
        ax.plot(centres, column(before, model, "median"), "o--", color=f"C{i}", alpha=0.6)
        ax.plot(centres, column(after, model, "median"), "o-", color=f"C{i}", label=model)
        lo, hi = column(after, model, "min"), column(after, model, "max")
        if np.any(hi > lo):
            ax.fill_between(centres, lo, hi, color=f"C{i}", alpha=0.2, lw=0)
    ax.axhline(1.0, color="k", ls=":", lw=1, label="no correction")
    ax.set_yscale("log")
    ax.set_xticks(centres, labels, fontsize=8)
    ax.set_xlabel(f"r / R_B, {report['config']['altitude_m']:g} m above the surface")
    ax.set_ylabel("relative field error")
    ax.set_title("(b) before (dashed) and after (solid) the descents", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def orders_figure(report: dict) -> Figure:
    """Mean exterior error against the number of orbits tracked (first repetition): the
    random orders (thin grey, min-max band), the D-optimal campaign (bold) and the fixed
    order (dashed)."""
    first = report["repetitions"][0]
    orders = first["orders"]
    n = np.asarray(orders["n_orbits"])

    def values(curve):
        return np.array([np.nan if v is None else v for v in curve], dtype=float)

    fig = Figure(figsize=(6.5, 4.2))
    ax = fig.add_subplot()
    random = [values(c) for c in orders.get("random", [])]
    for k, curve in enumerate(random):
        ax.plot(n, curve, "-", color="0.6", lw=0.8, label="random orders" if k == 0 else None)
    if random:
        table = np.vstack(random)
        ax.fill_between(n, table.min(axis=0), table.max(axis=0), color="0.85", lw=0)
    ax.plot(n, values(orders["fixed"]), "--", color="C1", lw=1.2, label="fixed order")
    if "d-optimal" in orders:
        ax.plot(n, values(orders["d-optimal"]), "o-", color="C0", lw=2.2, label="D-optimal")
    ax.set_yscale("log")
    ax.set_xticks(n)
    ax.set_xlabel("orbits tracked")
    ax.set_ylabel("mean exterior error, shells " + _shell_range(report["config"]) + " R_B")
    ax.set_title(f"{first['body']}, seed {first['seed']}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _shell_range(config: dict) -> str:
    shells = config["shells_rb"]
    return f"{min(shells):g}-{max(shells):g}"


def _iterates(best: list[int]) -> str:
    """The iterates an ensemble's members returned, e.g. "0, 37, 80 (by member)"."""
    return ", ".join(map(str, best)) + (" (by member)" if len(best) > 1 else "")


def _selects(rep: dict, model: str) -> bool:
    """Whether ``model``'s solver chooses its iterate on validation arcs (the network; SH
    runs to convergence and only leaves them out), as the repetition's fit records it."""
    return bool(rep.get("fits", {}).get(model, {}).get("select_on_validation"))

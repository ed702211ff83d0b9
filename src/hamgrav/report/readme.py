"""The frame of every results folder's README.md: title, the command that regenerates it,
the repetitions, the experiment's own lines, figures, notes and the configuration."""

from __future__ import annotations

__all__ = ["results_readme"]


def results_readme(
    title: str,
    report: dict,
    body: list[str],
    captions: dict[str, str],
    notes: str | None = None,
) -> list[str]:
    """README lines of the results ``report`` (results.json as a dict): the header, the
    experiment's ``body`` lines, the figures with their ``captions`` (file name -> caption),
    the hand-written ``notes`` (None: no notes) and the configuration table."""
    figures = report.get("figures", [])
    n = len(report["repetitions"])
    header = [
        f"# {title}",
        "",
        "Regenerate with:",
        "",
        f"    {report['command']}",
        "",
        f"{n} repetition(s), seeds {report['seeds'][0]}-{report['seeds'][-1]} "
        f"({report['dispatch']}), {report['wall_s']:.0f} s in all. "
        + (
            "Tables give the median over the repetitions and, in brackets, min-max."
            if n > 1
            else "One repetition: the tables give its values."
        ),
        "",
    ]
    if report.get("merged_from"):
        header += [
            "Merged (`hamgrav experiment merge`) from runs of the same config on other seeds, "
            "each repetition a function of its seed alone:",
            "",
            *(
                f"- seeds {run['seeds'][0]}-{run['seeds'][-1]}: `{run['command']}`"
                for run in report["merged_from"]
            ),
            "",
        ]
    lines = header + body
    if figures:
        lines += ["", "Figures:", ""] + [
            f"- `{name}`" + (f": {captions[name]}" if name in captions else "") for name in figures
        ]
    if notes is not None:
        lines += ["", "## Notes", "", notes.strip()]
    config = report["config"]
    lines += ["", "## Configuration", "", "| option | value |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in config.items()]
    return lines

"""Shared pieces of experiment reports: the results folder, results.json, text and figures,
each written atomically."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

from ..io import atomic_path  # noqa: E402


def start_report(results: dict, folder, command: str) -> tuple[dict, Path]:
    """Create ``folder``, write ``results.json`` (with the regenerating ``command``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    results = {**results, "command": command}
    with atomic_path(folder / "results.json") as tmp:
        tmp.write_text(json.dumps(results, indent=2) + "\n")
    return results, folder


def write_text(path: Path, lines: list[str]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines))


def save_figure(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)

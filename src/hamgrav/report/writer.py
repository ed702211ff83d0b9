"""Writing an experiment's folder: results.json, README.md and figures, each atomically."""

from __future__ import annotations

import json
from pathlib import Path

from ..files import atomic_path

__all__ = ["write_json", "write_text", "save_figure"]


def write_json(path: Path, data: dict) -> None:
    """``data`` as indented JSON at ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")


def write_text(path: Path, lines: list[str]) -> None:
    """``lines`` joined by newlines at ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines).rstrip("\n") + "\n")


def save_figure(fig, path: Path, dpi: int = 120) -> None:
    """A matplotlib figure as PNG at ``path``."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)

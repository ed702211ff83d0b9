"""What every experiment is made of: :class:`Experiment` (a frozen config type and a pure
function ``run(config, ctx)``), the :class:`RunContext` it runs in and the
:class:`RunOutput` it returns. Experiment modules import this module only, never the runner
(which finds them through :mod:`hamgrav.experiments.registry`)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

from ..report.tables import aggregate
from .config import ExperimentConfig

__all__ = ["Experiment", "RunContext", "RunOutput"]


@dataclass(frozen=True, eq=False)
class RunOutput:
    """One repetition's output: ``result`` (plain JSON-able data, goes into results.json) and
    ``artefacts`` (arrays and plain records for figures and files, not written as JSON)."""

    result: dict
    artefacts: dict = field(default_factory=dict)


def _silent(text: str) -> None:
    """Discard a progress line."""


@dataclass(frozen=True, eq=False)
class RunContext:
    """Everything a repetition uses besides its config, as plain values: its ``seed``, the
    body-data folder (``bodies_folder``, None: the default), ``say(text)`` for progress
    (rounded figures with units), ``mapper`` for independent work units (Kaula scans,
    candidate pools): builtin ``map``, or the cluster's when there is one, and
    ``fit_client``: the ``dask.distributed`` Client whose workers compute each fit's sums
    over arcs (None: in this process)."""

    seed: int
    bodies_folder: str | None = None
    say: Callable[[str], None] = _silent
    mapper: Callable = map
    fit_client: object | None = None


class Experiment(ABC):
    """An experiment of the paper: a config type and a pure function of (config, seed)."""

    #: command name (``hamgrav experiment NAME``)
    name: str = ""
    #: one-line description
    title: str = ""
    #: the frozen config dataclass
    config_type: type[ExperimentConfig] = ExperimentConfig
    #: keys of the single-run result holding {model: {statistic: number}}, aggregated
    aggregate_keys: tuple[str, ...] = ()
    #: default output folder
    default_output: str = ""
    #: what each figure file shows, in one sentence (README and console)
    figure_captions: dict[str, str] = {}

    def default_config(self) -> ExperimentConfig:
        """The config with every default."""
        return self.config_type()

    @abstractmethod
    def run(self, config: ExperimentConfig, ctx: RunContext) -> RunOutput:
        """One repetition of ``config`` (see :class:`RunContext` for ``ctx``)."""

    @abstractmethod
    def readme(self, report: dict) -> list[str]:
        """The README body (after the generic header) from results.json's content."""

    def figures(self, report: dict, artefacts: dict) -> dict:
        """Figures (file name -> matplotlib Figure) from the report and the first
        repetition's artefacts."""
        return {}

    def aggregate(self, repetitions: list[dict]) -> dict:
        """results.json's ``aggregate``: by default :func:`aggregate` over
        :attr:`aggregate_keys` (experiments with other result shapes override this)."""
        return aggregate(repetitions, self.aggregate_keys)

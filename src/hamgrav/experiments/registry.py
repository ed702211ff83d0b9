"""The table of experiments: command name -> ``module:class`` under
:mod:`hamgrav.experiments`. The runner reads this table and imports an experiment's module
only when it is asked for, so no experiment module is imported by the runner at import time
(and none imports the runner: they build on :mod:`hamgrav.experiments.base`).

A new experiment is one module with its :class:`~hamgrav.experiments.base.Experiment`
subclass, and one line here."""

from __future__ import annotations

import importlib

from ..errors import InputError
from .base import Experiment

__all__ = ["EXPERIMENTS", "get_experiment", "experiment_names"]

#: command name -> "module:class" (module relative to hamgrav.experiments)
EXPERIMENTS: dict[str, str] = {
    "anomalies": "anomalies:AnomaliesExperiment",
    "continual": "continual:ContinualExperiment",
    "deep": "deep:DeepExperiment",
    "deep-ladder": "ladder:DeepLadderExperiment",
    "descent": "descent:DescentExperiment",
    "interiors": "interiors:InteriorsExperiment",
    "own-body": "own_body:OwnBodyExperiment",
    "selection": "selection:SelectionExperiment",
    "solvers": "solvers:SolverExperiment",
    "swarm": "swarm:SwarmExperiment",
    "uncertainty": "uncertainty:UncertaintyExperiment",
}

_LOADED: dict[str, Experiment] = {}


def get_experiment(name: str) -> Experiment:
    """The experiment whose command name is ``name`` (its module imported on first use)."""
    if name not in EXPERIMENTS:
        raise InputError(f"unknown experiment {name!r}; known: {', '.join(experiment_names())}")
    if name not in _LOADED:
        module_name, class_name = EXPERIMENTS[name].split(":")
        module = importlib.import_module(f"{__package__}.{module_name}")
        _LOADED[name] = getattr(module, class_name)()
    return _LOADED[name]


def experiment_names() -> list[str]:
    """Command names of the experiments, sorted."""
    return sorted(EXPERIMENTS)

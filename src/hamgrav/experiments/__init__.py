"""The paper's experiments: each a frozen config and a pure function (config, seed) -> result,
run by :mod:`hamgrav.experiments.runner` (repetitions, Dask, results folder)."""

from .runner import experiment_names, get_experiment, run_experiment

__all__ = ["experiment_names", "get_experiment", "run_experiment"]

"""hamgrav: gravity fields of small bodies learned from tracking arcs.

``import hamgrav as hg`` gives the user-facing names below. They are loaded on first use
(PEP 562), so importing a light part of the package, e.g. the unit-free numerics in
:mod:`hamgrav.core`, never pulls in meshes, files or plotting.

Units: the numerics work in each body's canonical units (length = synchronous radius, time =
spin period / 2 pi, GM = 1); :class:`CanonicalUnits` converts to and from SI at the edge, and
every physical argument says its unit in its name (``_m``, ``_s``, ``_m_s``, ``_deg``, ``_rb``
for Brillouin radii).
"""

from importlib import import_module

__version__ = "0.2.0"

_EXPORTS = {
    # units and errors
    "CanonicalUnits": "units",
    "HamgravError": "errors",
    "InputError": "errors",
    "DatasetError": "errors",
    "HamgravWarning": "errors",
    # bodies and interiors
    "Body": "bodies.catalogue",
    "load_body": "bodies.catalogue",
    "list_bodies": "bodies.catalogue",
    "contact_binary": "bodies.catalogue",
    "read_body_toml": "bodies.files",
    "read_shape": "bodies.shapes",
    "Truth": "bodies.interiors",
    "build_truth": "bodies.interiors",
    "INTERIORS": "bodies.interiors",
    "fit_shape_prior": "bodies.shape_prior",
    "centred_shape_prior": "bodies.shape_prior",
    "polyhedron_potential": "bodies.polyhedron",
    "evaluation_sets": "bodies.evaluation",
    # campaign simulation
    "Arcs": "core.arcs",
    "OrbitFamily": "sim.tracking",
    "TrackingConfig": "sim.tracking",
    "orbit_grid": "sim.tracking",
    "simulate_orbits": "sim.tracking",
    "Campaign": "sim.campaign",
    "load_campaign": "sim.campaign",
    "simulate_campaign": "sim.campaign",
    # terms and models
    "MasconSet": "core.mascons",
    "GravityTerm": "core.terms",
    "register_term": "core.terms",
    "PointMass": "core.terms",
    "MasconTerm": "core.terms",
    "NeuralPotential": "core.terms",
    "SphericalHarmonics": "core.terms",
    "SolarRadiationPressure": "core.terms",
    "Model": "core.model",
    "evaluate_field": "core.model",
    "ArcProblem": "core.problem",
    # fitting
    "GravityEstimator": "fit.estimator",
    "FittedModel": "fit.fitted",
    "LevenbergMarquardt": "fit.lm",
    "Adam": "fit.adam",
    "Outcome": "fit.base",
    "SolveResult": "fit.base",
    "fit_continual": "fit.continual",
    "select_orbits": "fit.design",
    # evaluation
    "field_errors": "core.fields",
    "relative_field_error": "core.fields",
    "shell_points": "core.fields",
    # descents
    "DescentConfig": "sim.descent",
    "Touchdown": "sim.descent",
    "release_states": "sim.descent",
    "descend": "sim.descent",
    "miss_statistics": "sim.descent",
    # files
    "save_arcs": "io.arcs",
    "load_arcs": "io.arcs",
    "save_model": "io.models",
    "load_model": "io.models",
    "export_oem": "io.oem",
    "import_oem": "io.oem_import",
    "write_spk": "io.spk",
    "read_spk": "io.spk",
    "import_spk": "io.spk",
    "RotationModel": "bodies.rotation",
    "sh_export": "io.shformats",
    "write_icgem": "io.shformats",
    "write_shadr": "io.shformats",
    "write_network_json": "io.network_json",
    "formal_covariance": "fit.covariance",
    "uncertainty_report": "fit.covariance",
    "potential_sigma": "core.uncertainty",
    "residual_report": "fit.residuals",
    # experiments
    "run_experiment": "experiments.runner",
    "experiment_names": "experiments.runner",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'hamgrav' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *__all__])

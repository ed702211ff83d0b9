"""The checks that tell whether a fitted model and arcs belong together, and the formal
uncertainty of the potential, from Python (what ``hamgrav evaluate`` and ``export`` call)."""

from dataclasses import replace

import numpy as np
import pytest

from hamgrav.core.mascons import MasconSet
from hamgrav.errors import HamgravWarning, InputError
from hamgrav.fit.covariance import potential_uncertainty
from hamgrav.fit.estimator import GravityEstimator


@pytest.fixture(scope="module")
def fitted(small_arcs, synthetic_truth):
    est = GravityEstimator("sh", degree=2, validation_fraction=0.0, body=synthetic_truth.body)
    return est.fit(small_arcs).fitted_


def _other_truth(arcs):
    truth = arcs.truth
    return replace(arcs, truth=MasconSet(truth.positions * 1.01, truth.masses))


def test_another_truth_is_refused_and_an_old_model_warned_about(fitted, small_arcs):
    fitted.check_truth(small_arcs, "arcs.h5")  # the arcs it was fitted to
    with pytest.raises(InputError) as caught:
        fitted.check_truth(_other_truth(small_arcs), "other.h5", "model m.h5", "pass them")
    assert str(caught.value) == (
        "arcs other.h5 hold another truth than the one model m.h5 was fitted against (truth "
        "digests differ); pass them"
    )
    # fitted to arcs without a truth (imported tracking): any truth may serve
    replace(fitted, training={**fitted.training, "truth_sha256": None}).check_truth(
        _other_truth(small_arcs), "other.h5"
    )
    old = replace(fitted, training={})
    with pytest.warns(HamgravWarning, match="model file m.h5 does not record the truth"):
        old.check_truth(_other_truth(small_arcs), "other.h5", record="model file m.h5")


def test_the_recorded_arcs_file_and_the_expansion(fitted):
    assert fitted.recorded_arcs_file() is None  # fitted from memory
    recorded = fitted.with_arcs_file("arcs.h5")
    assert recorded.recorded_arcs_file().endswith("arcs.h5")
    only_solver = replace(recorded, training={})
    assert only_solver.recorded_arcs_file() == recorded.solver["arcs_file"]
    degree, radius = fitted.sh_expansion()
    assert degree == 2 and radius > 0
    assert replace(fitted, model=replace(fitted.model, learnable=None)).sh_expansion() is None


def test_potential_uncertainty_as_evaluate_reports_it(fitted, small_arcs, synthetic_truth):
    sets = {"r1.5": synthetic_truth.body.brillouin_radius * 1.5 * np.eye(3)}
    report = potential_uncertainty(fitted, small_arcs, synthetic_truth.body, sets)
    assert report["covariance"]["parameters_per_member"] == fitted.model.n_learn
    row = report["r1.5"]
    assert row["rms_sigma_v_m2_s2"] > 0 and 0 <= row["within_1_sigma"] <= 1  # with a truth
    quiet = replace(small_arcs, sigma_r_m=0.0, sigma_v_m_s=0.0)
    with pytest.raises(InputError, match="needs the arcs' tracking noise"):
        potential_uncertainty(fitted, quiet, synthetic_truth.body, sets)

"""A model and the arcs file it belongs with, and the export policy (what ``hamgrav evaluate``
and ``hamgrav export`` call): refused unless body, body model, frame and truth agree."""

from dataclasses import replace

import numpy as np
import pytest

from hamgrav.core.mascons import MasconSet
from hamgrav.core.model import Model
from hamgrav.core.terms import NeuralPotential, PointMass
from hamgrav.errors import InputError
from hamgrav.fit.estimator import GravityEstimator
from hamgrav.fit.fitted import FittedModel
from hamgrav.io.arcs import save_arcs
from hamgrav.io.model_arcs import sh_formal_covariance, truth_arcs
from hamgrav.io.shformats import PROJECTION_DEGREE, model_export


@pytest.fixture(scope="module")
def files(small_arcs, synthetic_truth, tmp_path_factory):
    folder = tmp_path_factory.mktemp("model_arcs")
    arcs_file = save_arcs(small_arcs, folder / "arcs.h5")
    est = GravityEstimator("sh", degree=2, validation_fraction=0.0, body=synthetic_truth.body)
    fitted = est.fit(small_arcs).fitted_.with_arcs_file(arcs_file)
    other = small_arcs.truth
    other_truth = replace(small_arcs, truth=MasconSet(other.positions * 1.01, other.masses))
    quiet = replace(small_arcs, sigma_r_m=0.0, sigma_v_m_s=0.0)
    return {
        "fitted": fitted,
        "arcs": arcs_file,
        "other_truth": save_arcs(other_truth, folder / "other.h5"),
        "quiet": save_arcs(quiet, folder / "quiet.h5"),
    }


def test_the_recorded_arcs_are_read_and_checked(files, small_arcs):
    fitted = files["fitted"]
    assert truth_arcs(fitted, "m.h5").digest() == small_arcs.digest()
    with pytest.raises(InputError) as caught:
        truth_arcs(fitted, "m.h5", files["other_truth"])
    assert str(caught.value) == (
        f"arcs {files['other_truth']} hold another truth than the one model m.h5 was fitted "
        "against (truth digests differ); pass the arcs of this model's campaign with --arcs"
    )
    with pytest.raises(InputError, match="model file m.h5 records no arcs file; pass --arcs"):
        truth_arcs(replace(fitted, training={}, solver={}), "m.h5")
    gone = fitted.with_arcs_file(files["arcs"].parent / "gone.h5")
    with pytest.raises(InputError, match="was fitted to, .*gone.h5, is gone"):
        truth_arcs(gone, "m.h5")
    with pytest.raises(InputError, match="are of body 'synthetic', model m.h5 of 'itokawa'"):
        truth_arcs(replace(fitted, body_name="itokawa"), "m.h5")


def test_formal_covariance_of_an_sh_model_from_its_arcs(files):
    fitted = files["fitted"]
    covariance, note = sh_formal_covariance(fitted)
    assert covariance.shape == (fitted.model.n_learn,) * 2 and note.startswith("formal errors")
    covariance, note = sh_formal_covariance(fitted, files["quiet"])
    assert covariance is None and "records no tracking noise" in note
    covariance, note = sh_formal_covariance(replace(fitted, training={}, solver={}))
    assert covariance is None and "arcs file is not there" in note
    moved = replace(fitted, body_origin_m=(0.0, 0.0, 1.0))
    with pytest.raises(InputError, match=r"\(another campaign\); pass the model's arcs"):
        sh_formal_covariance(moved)


def test_the_export_policy(files, synthetic_truth):
    fitted = files["fitted"]
    own = model_export(fitted)
    assert (own.degree, own.reference_radius_m) == (
        2,
        fitted.sh_expansion()[1] * fitted.units.length_m,
    )
    term = NeuralPotential((4,))
    network = FittedModel(
        Model((PointMass(),), term),
        term.initial_params(1),
        "synthetic",
        fitted.gm_m3_s2,
        fitted.spin_period_s,
    )
    body = synthetic_truth.body
    projected = model_export(network, body=body)
    assert projected.degree == PROJECTION_DEGREE
    assert np.isclose(projected.reference_radius_m, body.brillouin_radius_m)
    assert model_export(network, degree=3, body=body).degree == 3

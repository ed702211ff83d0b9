"""A set of arcs weighed at a share of the cost (hamgrav.fit.weights), measured by what no
correction leaves (GravityEstimator.no_correction_costs)."""

import numpy as np
import pytest

from hamgrav.core.problem import ArcProblem
from hamgrav.errors import InputError
from hamgrav.fit.estimator import GravityEstimator
from hamgrav.fit.weights import share_weights


def test_no_correction_costs_are_the_known_parts(small_arcs, synthetic_truth):
    est = GravityEstimator("network", hidden=(4,), body=synthetic_truth.body, harmonic="cv")
    costs = est.no_correction_costs(small_arcs)
    sh = GravityEstimator("sh", degree=3, body=synthetic_truth.body)
    sh_model, _ = sh.build_model(small_arcs)
    reference = ArcProblem(sh_model, small_arcs).arc_costs(np.zeros(sh_model.n_learn))
    # the learnable term is zero: a network's and SH's known parts are the same point mass
    np.testing.assert_allclose(costs, reference, rtol=1e-10)
    assert costs.shape == (small_arcs.n_arcs,) and np.all(costs > 0)
    weighted = GravityEstimator("sh", degree=3, body=synthetic_truth.body, weighted=True)
    assert weighted.no_correction_costs(small_arcs).sum() > 1e3 * costs.sum()


@pytest.mark.parametrize("share", [0.2, 0.5, 0.9])
def test_the_set_holds_its_share_with_no_correction(share):
    costs = np.array([1.0, 3.0, 2.0, 500.0, 40.0])
    in_set = np.array([False, False, False, True, True])
    w = share_weights(costs, in_set, share)
    assert np.all(w[~in_set] == 1.0)
    assert np.all(w[in_set] == w[3])
    weighted = w * costs
    assert weighted[in_set].sum() / weighted.sum() == pytest.approx(share, rel=1e-12)


@pytest.mark.parametrize(
    "costs, in_set, share, message",
    [
        ([1.0, 2.0], [False, True], 1.0, "lie in \\(0, 1\\)"),
        ([1.0, 2.0], [False, True], 0.0, "lie in \\(0, 1\\)"),
        ([1.0, 2.0], [False, False], 0.2, "set arcs' cost with no correction is 0 over 0"),
        ([1.0, 0.0], [False, True], 0.2, "set arcs' cost"),
        ([np.inf, 2.0], [False, True], 0.2, "other arcs' cost"),
        ([1.0, 2.0], [False], 0.2, "one entry per arc"),
    ],
)
def test_a_share_without_arcs_to_measure_it_is_refused(costs, in_set, share, message):
    with pytest.raises(InputError, match=message):
        share_weights(np.array(costs), np.array(in_set), share)

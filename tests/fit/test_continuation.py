"""Continuing a fitted model on more arcs from Python, with the checks the command line
makes: the structure, the body, the frame; the stage history; the checkpoint identity."""

from dataclasses import replace

import numpy as np
import pytest

from hamgrav.errors import InputError
from hamgrav.fit.estimator import GravityEstimator


def _scaled(mesh, factor):
    out = mesh.copy()
    out.apply_scale(factor)
    return out


def _sh(body, **kw):
    return GravityEstimator("sh", degree=2, validation_fraction=0.0, body=body, **kw)


@pytest.fixture(scope="module")
def first(small_arcs, synthetic_truth):
    return _sh(synthetic_truth.body).fit(small_arcs.subset(np.arange(6))).fitted_


def test_a_continued_fit_is_a_warm_stage_with_its_history(first, small_arcs, synthetic_truth):
    est = _sh(synthetic_truth.body).continue_fit(first, small_arcs)
    stages = est.fitted_.stages
    assert [s["stage"] for s in stages] == [0, 1]
    assert stages[0]["n_arcs"] == 6 and stages[1]["n_arcs"] == 9
    assert stages[1]["warm_started"] and "warm_started" not in stages[0]
    assert est.result_.initial_cost == pytest.approx(
        _sh(synthetic_truth.body).fit(small_arcs, init=first.params).result_.initial_cost
    )
    # a third stage keeps the first two
    third = _sh(synthetic_truth.body).continue_fit(est.fitted_, small_arcs)
    assert [s["stage"] for s in third.fitted_.stages] == [0, 1, 2]
    recorded = third.fitted_.with_arcs_file("arcs.h5")
    assert recorded.stages[-1]["arcs_file"].endswith("arcs.h5")
    assert recorded.solver["arcs_file"] == recorded.training["arcs_file"]


def test_a_model_of_another_structure_body_or_frame_is_not_continued(
    first, small_arcs, synthetic_truth
):
    body = synthetic_truth.body
    with pytest.raises(InputError, match="has structure .* continue a model with the same"):
        GravityEstimator("sh", degree=3, body=body).continue_fit(first, small_arcs)
    with pytest.raises(InputError, match="give the degree, not a choice"):
        GravityEstimator("sh", degree="auto", body=body).continue_fit(first, small_arcs)
    moved = replace(first, body_origin_m=(0.0, 0.0, 1.0))
    with pytest.raises(InputError, match="another campaign"):
        _sh(body).continue_fit(moved, small_arcs)
    heavier = replace(first, gm_m3_s2=first.gm_m3_s2 * 1.01)
    with pytest.raises(InputError, match="another body model"):
        _sh(body).continue_fit(heavier, small_arcs)


def test_the_checkpoint_identity_tells_fits_apart(first, small_arcs, synthetic_truth, tmp_path):
    body = synthetic_truth.body
    est = _sh(body)
    base = est.checkpoint_identity(small_arcs, est.make_solver())
    assert base == _sh(body).checkpoint_identity(small_arcs, est.make_solver())
    assert base["settings"]["degree"] == 2 and base["init_params_sha256"] is None
    others = [
        _sh(body, seed=1).checkpoint_identity(small_arcs, est.make_solver()),
        _sh(body, kaula=1e-6).checkpoint_identity(small_arcs, est.make_solver()),
        est.checkpoint_identity(small_arcs.subset(np.arange(6)), est.make_solver()),
        est.checkpoint_identity(small_arcs, est.make_solver(), init=first),
    ]
    # another shape given for the same arcs (same GM and spin: only warned about)
    with pytest.warns(UserWarning, match="another shape"):
        others.append(
            _sh(replace(body, mesh_m=_scaled(body.mesh_m, 1.01))).checkpoint_identity(
                small_arcs, est.make_solver()
            )
        )
    # the same fit with arc weights, or other weights, is another fit
    from hamgrav.io.fit_run import prepare_fit

    weighed = [
        prepare_fit(est, small_arcs, tmp_path / f"w{k}.h5", arc_weights=w).identity
        for k, w in enumerate([None, np.ones(9), np.linspace(1, 2, 9)])
    ]
    assert weighed[0] == base
    others += weighed[1:]
    assert weighed[1] != weighed[2]
    assert all(other != base for other in others)
    # no softening: the identity of the checkpoints written before the option existed
    assert "envelope_softening_rb" not in base["settings"]
    soft = GravityEstimator("network", hidden=(4,), envelope_softening_rb=0.3, body=body)
    assert (
        soft.checkpoint_identity(small_arcs, soft.make_solver())["settings"][
            "envelope_softening_rb"
        ]
        == 0.3
    )
    import json

    json.dumps(base)  # plain data: it is written into the checkpoint

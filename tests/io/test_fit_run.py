"""A fit that writes its model file from Python, as ``hamgrav fit`` does: the checkpoint
beside it, resuming it (only the fit that wrote it), continuing an earlier model."""

from dataclasses import replace

import numpy as np
import pytest

from hamgrav.errors import InputError
from hamgrav.fit.estimator import GravityEstimator
from hamgrav.io import models
from hamgrav.io.arcs import save_arcs
from hamgrav.io.fit_run import checkpoint_for_fit, checkpoint_progress, fit_to_file, prepare_fit
from hamgrav.io.models import ModelFileError, checkpoint_path_for, load_model, save_checkpoint


def _sh(body, degree=2, **kw):
    return GravityEstimator("sh", degree=degree, validation_fraction=0.0, body=body, **kw)


@pytest.fixture(scope="module")
def arcs_file(small_arcs, tmp_path_factory):
    return save_arcs(small_arcs, tmp_path_factory.mktemp("arcs") / "arcs.h5")


def test_a_fit_writes_its_model_and_leaves_no_checkpoint(arcs_file, synthetic_truth, tmp_path):
    out = tmp_path / "m.h5"
    written = fit_to_file(_sh(synthetic_truth.body), arcs_file, out)
    back = load_model(out)
    assert back.training["arcs_file"] == str(arcs_file.resolve()) == written.recorded_arcs_file()
    np.testing.assert_array_equal(back.params, written.params)
    assert not checkpoint_path_for(out).exists()


def test_the_checkpoint_is_checked_before_any_work(tmp_path):
    out = tmp_path / "m.h5"
    with pytest.raises(InputError, match="no checkpoint .* to resume from; run without"):
        checkpoint_for_fit(out, resume=True)
    checkpoint_path_for(out).write_bytes(b"")
    with pytest.raises(InputError, match="a checkpoint of an interrupted fit exists"):
        checkpoint_for_fit(out, resume=False)
    assert checkpoint_for_fit(out, resume=True) == checkpoint_path_for(out)


def test_an_interrupted_fit_resumes_to_the_uninterrupted_result(
    small_arcs, synthetic_truth, tmp_path, monkeypatch
):
    body = synthetic_truth.body
    whole = fit_to_file(_sh(body), small_arcs, tmp_path / "whole.h5")
    out = tmp_path / "m.h5"
    real_save = models.save_checkpoint

    def save_then_interrupt(*args):
        real_save(*args)
        raise KeyboardInterrupt

    monkeypatch.setattr(models, "save_checkpoint", save_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        fit_to_file(_sh(body), small_arcs, out)
    monkeypatch.setattr(models, "save_checkpoint", real_save)
    ckpt = checkpoint_path_for(out)
    assert ckpt.exists() and not out.exists()
    assert checkpoint_progress(ckpt).startswith("LM iteration")
    with pytest.raises(InputError, match="a checkpoint of an interrupted fit exists"):
        fit_to_file(_sh(body), small_arcs, out)  # not started over
    resumed = fit_to_file(_sh(body), small_arcs, out, resume=True)
    np.testing.assert_allclose(resumed.params, whole.params, rtol=1e-10, atol=1e-14)
    assert not ckpt.exists()


def test_a_checkpoint_of_another_fit_or_body_is_not_resumed(small_arcs, synthetic_truth, tmp_path):
    body = synthetic_truth.body
    out = tmp_path / "m.h5"
    ckpt = checkpoint_path_for(out)
    est = _sh(body)
    theta = est.initial_params(est.build_model(small_arcs)[0], small_arcs)
    other = _sh(body, seed=3)
    save_checkpoint(ckpt, theta, {"iteration": 1}, other.checkpoint_identity(
        small_arcs, other.make_solver()
    ))  # fmt: skip
    with pytest.raises(ModelFileError, match="belongs to another fit: settings.seed 3"):
        prepare_fit(_sh(body), small_arcs, out, resume=True)
    mesh = body.mesh_m.copy()
    mesh.apply_scale(1.01)
    with pytest.warns(UserWarning, match="another shape"):
        bigger = _sh(replace(body, mesh_m=mesh))
        identity = bigger.checkpoint_identity(small_arcs, bigger.make_solver())
    save_checkpoint(ckpt, theta, {"iteration": 1}, identity)
    with pytest.raises(ModelFileError, match="belongs to another fit: body.mesh_sha256"):
        prepare_fit(_sh(body), small_arcs, out, resume=True)


def test_a_model_is_continued_as_a_stage_and_checked_first(small_arcs, synthetic_truth, tmp_path):
    body = synthetic_truth.body
    first = tmp_path / "first.h5"
    fit_to_file(_sh(body), small_arcs.subset(np.arange(6)), first)
    out = tmp_path / "second.h5"
    second = fit_to_file(_sh(body), small_arcs, out, init=first)
    assert [s["stage"] for s in load_model(out).stages] == [0, 1]
    assert second.stages[1]["warm_started"] and second.stages[1]["n_arcs"] == 9
    with pytest.raises(InputError, match=f"^model to continue {first}: the model to continue"):
        fit_to_file(_sh(body, degree=3), small_arcs, tmp_path / "third.h5", init=first)
    with pytest.raises(InputError, match="^--init: the model to continue has structure"):
        prepare_fit(
            _sh(body, degree=3), small_arcs, tmp_path / "t.h5", init=first, init_name="--init"
        )
    # the identity of a continued fit names its starting model: a fresh fit's checkpoint differs
    fresh = prepare_fit(_sh(body), small_arcs, tmp_path / "a.h5")
    continued = prepare_fit(_sh(body), small_arcs, tmp_path / "b.h5", init=first)
    assert continued.identity["init_params_sha256"] == load_model(first).params_sha256()
    assert fresh.identity["init_params_sha256"] is None

import json
from collections import OrderedDict

import h5py
import numpy as np
import pytest

import hamgrav.core.model
from hamgrav.core.mascons import MasconSet
from hamgrav.core.model import Model, evaluate_field
from hamgrav.core.terms import (
    MasconTerm,
    NeuralPotential,
    PointMass,
    SolarRadiationPressure,
    SphericalHarmonics,
)
from hamgrav.errors import DatasetError, HamgravWarning
from hamgrav.fit.fitted import FittedModel
from hamgrav.io import models as modelfile
from hamgrav.io.models import (
    ModelFileError,
    checkpoint_path_for,
    load_checkpoint,
    load_model,
    save_checkpoint,
    save_model,
)

POINTS = np.array([[1.3, 0.2, -0.1], [-0.7, 1.1, 0.4], [0.1, -0.2, 2.5], [2.0, 2.0, 0.0]])


def _fitted(model: Model, rng, *, n_srp: int = 0, **kwargs) -> FittedModel:
    defaults = dict(
        body_name="itokawa",
        gm_m3_s2=2.36,
        spin_period_s=43632.0,
        body_origin_m=(1.5, -2.25, 0.125),
        prior={"kind": "shape", "density": 1.9, "notes": ["a", None, True]},
        solver={"name": "levenberg-marquardt", "tol": 1e-10, "max_iter": 50},
        history={
            "cost": rng.random(7).tolist(),
            "iteration": list(range(7)),
            "per_arc": rng.random((3, 2)).tolist(),
            "events": ["start", {"restart": 3}],
            "converged": True,
            "empty": [],
            "names": [1.0, 2.0],  # names the file itself uses
            "json": "text",
            "a/b": [0.5],
        },
        stages=[{"stage": 0, "arcs": 4, "cost": 0.5}, {"stage": 1, "arcs": 8, "cost": 0.25}],
    )
    defaults.update(kwargs)
    params = rng.normal(size=model.n_learn + n_srp)
    return FittedModel(model=model, params=params, estimate_trajectory_params=n_srp > 0, **defaults)


@pytest.fixture
def nn_fitted(rng):
    return _fitted(Model((PointMass(),), NeuralPotential((4,))), rng)


@pytest.fixture
def sh_fitted(rng):
    return _fitted(Model((PointMass(),), SphericalHarmonics(4, 0.6)), rng)


@pytest.fixture
def mascon_fitted(rng):
    mascons = MasconSet(rng.normal(size=(5, 3)) * 0.3, np.full(5, 0.2))
    model = Model(
        (MasconTerm(mascons, "shape prior"),),
        NeuralPotential((3,), scale=0.05),
        (SolarRadiationPressure(1e-3, 12.5),),
    )
    return _fitted(model, rng, n_srp=3)


def _assert_same(back: FittedModel, fitted: FittedModel) -> None:
    assert back.model.key() == fitted.model.key()
    assert back.model.describe() == fitted.model.describe()
    assert back.params.dtype == np.float64
    assert np.array_equal(back.params, fitted.params)
    for name in (
        "body_name",
        "gm_m3_s2",
        "spin_period_s",
        "body_origin_m",
        "estimate_trajectory_params",
    ):
        assert getattr(back, name) == getattr(fitted, name), name
    assert back.prior == fitted.prior
    assert back.solver == fitted.solver
    assert back.stages == fitted.stages
    assert list(back.history) == list(fitted.history)
    for name, value in fitted.history.items():
        assert back.history[name] == value, name
    assert np.array_equal(back.history["cost"], fitted.history["cost"])


@pytest.mark.parametrize("which", ["nn_fitted", "sh_fitted", "mascon_fitted"])
def test_round_trip_exact(which, request, tmp_path, monkeypatch):
    fitted = request.getfixturevalue(which)
    before = {
        part: evaluate_field(fitted.model, fitted.params, POINTS, part)
        for part in ("learnable", "total")
    }
    path = save_model(fitted, tmp_path / "model.h5")
    assert list(tmp_path.iterdir()) == [path]  # no temporary left behind
    monkeypatch.setattr(
        hamgrav.core.model, "_CACHE", OrderedDict()
    )  # the loaded model compiles afresh
    back = load_model(path, expect_body="itokawa", expect_structure=fitted.model.key())
    _assert_same(back, fitted)
    for part, (v, a) in before.items():
        v2, a2 = evaluate_field(back.model, back.params, POINTS, part)
        assert np.array_equal(v, v2) and np.array_equal(a, a2), part


def test_file_layout(mascon_fitted, tmp_path):
    path = save_model(mascon_fitted, tmp_path / "model.h5")
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == "hamgrav-model"
        assert f.attrs["format_version"] == 2
        assert f.attrs["hamgrav_version"] == hamgrav.__version__
        assert f.attrs["structure_key"] == mascon_fitted.model.key()
        assert "synchronous radius" in f.attrs["units"]
        assert f["params"].shape == (mascon_fitted.model.n_learn + 3,)
        assert f["history/cost"].dtype == np.float64
        assert f["history/per_arc"].shape == (3, 2)
        assert "events" not in f["history"] and "events" in f["history"].attrs["json"]


def test_many_mascons_fit_in_the_file(rng, tmp_path):
    mascons = MasconSet(rng.normal(size=(5000, 3)), np.full(5000, 1 / 5000))
    fitted = _fitted(Model((MasconTerm(mascons),), NeuralPotential((2,))), rng)
    back = load_model(save_model(fitted, tmp_path / "big.h5"))
    assert back.model.key() == fitted.model.key()
    assert np.array_equal(back.model.known[0].mascons.positions, mascons.positions)


def test_truncated_file(nn_fitted, tmp_path):
    path = save_model(nn_fitted, tmp_path / "model.h5")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelFileError, match="model.h5 is truncated, corrupted or was edited"):
        load_model(path)


def test_corrupted_bytes(nn_fitted, tmp_path):
    path = save_model(nn_fitted, tmp_path / "model.h5")
    data = bytearray(path.read_bytes())
    data[:64] = b"\x00" * 64
    path.write_bytes(bytes(data))
    with pytest.raises(ModelFileError, match="model.h5 is truncated, corrupted"):
        load_model(path)


def test_error_is_a_dataset_error(tmp_path):
    assert issubclass(ModelFileError, DatasetError)
    with pytest.raises(DatasetError, match="model file not found: .*missing.h5"):
        load_model(tmp_path / "missing.h5")


def test_other_files_refused(nn_fitted, tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = "hamgrav-arcs"
    with pytest.raises(ModelFileError, match="not a hamgrav model file"):
        load_model(other)
    text = tmp_path / "notes.h5"
    text.write_text("hello")
    with pytest.raises(ModelFileError, match="notes.h5 is truncated, corrupted"):
        load_model(text)


def test_newer_version_asks_for_upgrade(nn_fitted, tmp_path, old_hdf5):
    path = save_model(nn_fitted, tmp_path / "model.h5")
    with old_hdf5(path) as f:
        f.attrs["format_version"] = 3
    with pytest.raises(ModelFileError, match="upgrade hamgrav"):
        load_model(path)


def test_inconsistent_structure_key(nn_fitted, tmp_path, old_hdf5):
    path = save_model(nn_fitted, tmp_path / "model.h5")
    with old_hdf5(path) as f:
        f.attrs["structure_key"] = "pm(1.0)|learn:nn((8,),0.1,1.0)|traj:none"
    with pytest.raises(ModelFileError, match="file inconsistent"):
        load_model(path)


def test_wrong_params_length(nn_fitted, mascon_fitted, tmp_path, old_hdf5):
    path = save_model(nn_fitted, tmp_path / "model.h5")
    with old_hdf5(path) as f:
        del f["params"]
        f["params"] = np.zeros(nn_fitted.model.n_learn + 1)
    with pytest.raises(ModelFileError, match="file inconsistent: .*learnable parameters"):
        load_model(path)
    path = save_model(mascon_fitted, tmp_path / "srp.h5")
    with old_hdf5(path) as f:
        del f["params"]
        f["params"] = np.zeros(mascon_fitted.model.n_learn - 1)
    with pytest.raises(ModelFileError, match="are not 16 learnable plus whole trajectories"):
        load_model(path)
    bad = FittedModel(nn_fitted.model, np.zeros(3), "itokawa", 1.0, 1.0)
    with pytest.raises(ValueError, match="cannot save"):
        save_model(bad, tmp_path / "bad.h5")
    assert not (tmp_path / "bad.h5").exists()


def test_expect_body(nn_fitted, tmp_path):
    path = save_model(nn_fitted, tmp_path / "model.h5")
    with pytest.raises(
        ModelFileError,
        match="model.h5 was fitted for body 'itokawa', not 'bennu'; fit a model for this body",
    ):
        load_model(path, expect_body="bennu")


def test_expect_structure(nn_fitted, sh_fitted, tmp_path):
    path = save_model(nn_fitted, tmp_path / "model.h5")
    expected = sh_fitted.model.key()
    with pytest.raises(ModelFileError) as info:
        load_model(path, expect_structure=expected)
    message = str(info.value)
    assert nn_fitted.model.key() in message and expected in message
    assert "model.h5" in message


def test_failed_save_leaves_nothing(nn_fitted, tmp_path, monkeypatch):
    def boom(group, history):
        group["partial"] = np.zeros(3)
        raise RuntimeError("boom")

    monkeypatch.setattr(modelfile, "_write_history", boom)
    with pytest.raises(RuntimeError, match="boom"):
        save_model(nn_fitted, tmp_path / "model.h5")
    assert list(tmp_path.iterdir()) == []


def test_failed_save_keeps_previous_file(nn_fitted, sh_fitted, tmp_path, monkeypatch):
    path = save_model(nn_fitted, tmp_path / "model.h5")
    unjsonable = FittedModel(
        sh_fitted.model, sh_fitted.params, "itokawa", 1.0, 1.0, stages=[object()]
    )
    with pytest.raises(TypeError, match="stages must be plain"):
        save_model(unjsonable, path)
    monkeypatch.setattr(modelfile, "_write_history", lambda g, h: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        save_model(sh_fitted, path)
    assert list(tmp_path.iterdir()) == [path]
    _assert_same(load_model(path), nn_fitted)


def test_checkpoint_round_trip_exact(rng, tmp_path):
    params = rng.normal(size=41)
    state = {
        "iteration": 12,
        "lambda": 1e-3,
        "cost_history": [3.0, 2.5, 2.25],
        "settings": {"tol": 1e-12, "arcs": [0, 2, 5], "name": "lm", "done": False, "x": None},
        "jtj": rng.normal(size=(4, 4)),
        "mask": np.array([True, False, True]),
        "seed": np.int64(7),
        "step": np.float32(0.5),
    }
    path = save_checkpoint(tmp_path / "fit.ckpt.npz", params, state)
    assert list(tmp_path.iterdir()) == [path]
    back_params, back_state = load_checkpoint(path)
    assert back_params.dtype == params.dtype and np.array_equal(back_params, params)
    assert list(back_state) == list(state)
    for key, value in state.items():
        if isinstance(value, np.ndarray | np.generic):
            assert type(back_state[key]) is type(value), key
            assert back_state[key].dtype == value.dtype, key
            assert np.array_equal(back_state[key], value), key
        else:
            assert back_state[key] == value, key


def test_checkpoint_name_kept_and_path_for(rng, tmp_path):
    ckpt = checkpoint_path_for(tmp_path / "itokawa.h5")
    assert ckpt == tmp_path / "itokawa.h5.checkpoint.npz"
    save_checkpoint(tmp_path / "plain", np.zeros(2), {})
    assert (tmp_path / "plain").is_file() and not (tmp_path / "plain.npz").exists()
    params, state = load_checkpoint(tmp_path / "plain")
    assert np.array_equal(params, np.zeros(2)) and state == {}


def test_checkpoint_errors(tmp_path):
    with pytest.raises(ModelFileError, match="checkpoint file not found"):
        load_checkpoint(tmp_path / "none.npz")
    path = save_checkpoint(tmp_path / "c.npz", np.arange(50.0), {"a": 1})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelFileError, match="c.npz is truncated, corrupted"):
        load_checkpoint(path)
    with pytest.raises(TypeError, match="object array"):
        save_checkpoint(tmp_path / "o.npz", np.zeros(1), {"o": np.array([object()])})
    with pytest.raises(TypeError, match="plain data"):
        save_checkpoint(tmp_path / "s.npz", np.zeros(1), {"s": {1, 2}})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.npz"]
    # a model file where the checkpoint should be (not: "pickled data", numpy's own words)
    model_like = tmp_path / "m.npz"
    with h5py.File(model_like, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(ModelFileError, match="m.npz is an HDF5 file, not a hamgrav checkpoint"):
        load_checkpoint(model_like)


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("gm_m3_s2", 0.0, "'gm_m3_s2' must be a finite number > 0"),
        ("spin_period_s", 0.0, "'spin_period_s' must be a finite number > 0"),
        ("body_origin_m", [0.0, np.inf, 0.0], "'body_origin_m' must be 3 finite numbers"),
    ],
)
def test_unsealed_attributes_checked(mascon_fitted, tmp_path, old_hdf5, name, value, message):
    path = save_model(mascon_fitted, tmp_path / "m.h5")
    with old_hdf5(path) as f:
        f.attrs[name] = value
    with pytest.raises(ModelFileError, match=message):
        load_model(path)


def test_params_of_no_number_type_refused(nn_fitted, tmp_path, old_hdf5):
    path = save_model(nn_fitted, tmp_path / "m.h5")
    with old_hdf5(path) as f:
        del f["params"]
        f["params"] = np.ones(nn_fitted.model.n_learn, dtype=bool)
    with pytest.raises(ModelFileError, match="'params' holds bool, expected real numbers"):
        load_model(path)


def _rewrite_header(path, change):
    """Rewrite a checkpoint with its JSON header changed by ``change(header)``."""
    with np.load(path, allow_pickle=False) as data:
        entries = {k: data[k] for k in data.files}
    header = json.loads(str(entries["header"][0]))
    change(header)
    entries["header"] = np.array([json.dumps(header)])
    with open(path, "wb") as fh:
        np.savez(fh, allow_pickle=False, **entries)


def test_checkpoint_header_checked(tmp_path):
    path = save_checkpoint(tmp_path / "c.npz", np.zeros(3), {"solver": "lm"})
    _rewrite_header(path, lambda h: h.update(format="something-else"))
    with pytest.raises(ModelFileError, match="not a hamgrav checkpoint .*something-else"):
        load_checkpoint(path)
    # written before checkpoints recorded their fit: only the solver can be compared
    path = save_checkpoint(tmp_path / "old.npz", np.zeros(3), {"solver": "lm"})
    _rewrite_header(path, lambda h: h.pop("identity", None))
    with pytest.raises(ModelFileError, match="written by the 'lm' solver, this fit runs 'adam'"):
        load_checkpoint(path, expect={"solver": "adam"})
    with pytest.warns(HamgravWarning, match="does not record which fit wrote it"):
        params, state = load_checkpoint(path, expect={"solver": "lm"})
    assert state == {"solver": "lm"} and np.array_equal(params, np.zeros(3))


@pytest.mark.parametrize("value", ["abc", np.zeros((2, 2, 2))])
def test_non_numeric_attributes_are_named(mascon_fitted, tmp_path, old_hdf5, value):
    path = save_model(mascon_fitted, tmp_path / "m.h5")
    with old_hdf5(path) as f:
        f.attrs["gm_m3_s2"] = value
    with pytest.raises(ModelFileError, match="'gm_m3_s2' must be a") as info:
        load_model(path)
    assert "\n" not in str(info.value)  # one line, even for an array


def test_version_1_file_with_srp_slot_is_read(mascon_fitted, tmp_path, old_hdf5):
    """A model file of format 1 (one SRP slot) reads back as a per-trajectory term."""
    import json

    path = save_model(mascon_fitted, tmp_path / "v1.h5")
    with old_hdf5(path) as f:
        description = json.loads(f.attrs["model"])
        description["srp"] = description.pop("per_trajectory")[0]
        f.attrs["model"] = json.dumps(description)
        f.attrs["format_version"] = 1
        f.attrs["structure_key"] = f.attrs["structure_key"].replace("|traj:", "|srp:")
        f.attrs["estimate_srp"] = f.attrs["estimate_trajectory_params"]
        del f.attrs["estimate_trajectory_params"]
        del f.attrs["training"]  # format 1 had no record of its training arcs
    with pytest.warns(HamgravWarning, match="v1.h5 has no hamgrav checksum"):
        back = load_model(path)
    assert back.model.key() == mascon_fitted.model.key()
    assert back.estimate_trajectory_params

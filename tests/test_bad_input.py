"""Bad input gets a clear one-line error (status 2), never a traceback and never a wrong
answer: one case per class of the failures found by trying to break hamgrav."""

import json
import os
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from hamgrav.cli import app
from hamgrav.core.mascons import MasconSet
from hamgrav.errors import DatasetError, HamgravWarning
from hamgrav.io.arcs import load_arcs, save_arcs
from hamgrav.io.models import checkpoint_path_for, load_model, save_checkpoint
from hamgrav.io.oem import export_oem_by_trajectory

runner = CliRunner()


def _error(result, *needles):
    """The run failed as a user error: status 2, one 'error:' line holding every needle."""
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    text = " ".join(result.output.split())
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in text, (needle, text)
    return text


@pytest.fixture(scope="module")
def files(tmp_path_factory, small_arcs):
    """An arcs file and an SH 2 model fitted to it (absolute paths)."""
    folder = tmp_path_factory.mktemp("bad-input")
    arcs = save_arcs(small_arcs, folder / "arcs.h5")
    model = folder / "sh2.h5"
    result = runner.invoke(app, ["fit", str(arcs), "--model", "sh:2", "-o", str(model)])
    assert result.exit_code == 0, result.output
    return arcs, model


def _rewrite(path, name, change):
    """Change dataset ``name`` of an HDF5 file in place, as a corrupting tool would."""
    with h5py.File(path, "a") as f:
        data = change(f[name][()])
        del f[name]
        f[name] = data


# -------------------------------------------------------------------- 1. non-finite numbers
def test_nan_parameter_is_refused_not_evaluated(files, tmp_path, old_hdf5):
    _, model = files
    bad = tmp_path / "nan.h5"
    bad.write_bytes(model.read_bytes())

    def nan_first(p):
        p[0] = np.nan
        return p

    _rewrite(bad, "params", nan_first)
    _error(runner.invoke(app, ["evaluate", str(bad), "--json"]), str(bad), "corrupted")
    with old_hdf5(bad):  # as an older hamgrav wrote it (no checksum): the values speak
        pass
    text = _error(runner.invoke(app, ["evaluate", str(bad), "--json"]), str(bad))
    assert "non-finite values" in text and "fit the model again" in text


def test_old_model_files_recording_other_arcs_or_body_are_refused(files, tmp_path, old_hdf5):
    # files without the checksum (older hamgrav) are read as they are: their values speak
    arcs, model = files
    odd = tmp_path / "odd.h5"
    odd.write_bytes(model.read_bytes())
    with old_hdf5(odd) as f:
        training = json.loads(f.attrs["training"])
        f.attrs["training"] = json.dumps({**training, "arcs_file": 123})
    _error(runner.invoke(app, ["evaluate", str(odd)]), "records its arcs file as 123")
    result = runner.invoke(
        app, ["export", str(odd), "--format", "icgem", "-o", str(tmp_path / "g")]
    )
    assert result.exit_code == 0 and "no formal errors" in " ".join(result.output.split())
    heavy = tmp_path / "heavy.h5"
    heavy.write_bytes(model.read_bytes())
    with old_hdf5(heavy) as f:
        del f["body"]  # as older hamgrav wrote it: no record of the body
        f.attrs["gm_m3_s2"] = 1e9
    _error(runner.invoke(app, ["evaluate", str(heavy)]), "gm_m3_s2", "another body model")
    _error(
        runner.invoke(
            app, ["export", str(heavy), "--format", "icgem", "-o", str(tmp_path / "h.gfc")]
        ),
        "gm_m3_s2",
    )
    assert not (tmp_path / "h.gfc").exists()


def test_flipped_byte_in_arcs_is_refused(files, tmp_path):
    arcs, _ = files
    data = bytearray(arcs.read_bytes())
    with h5py.File(arcs) as f:  # flip one byte inside the states' data
        offset = f["states"].id.get_offset() or f["states"].id.get_chunk_info(0).byte_offset
    data[offset + 100] ^= 0x01
    bad = tmp_path / "flipped.h5"
    bad.write_bytes(bytes(data))
    _error(
        runner.invoke(app, ["fit", str(bad), "--model", "sh:2", "-o", str(tmp_path / "m.h5")]),
        str(bad),
        "corrupted",
    )
    assert not (tmp_path / "m.h5").exists()


def test_huge_state_is_refused_before_propagation(small_arcs, tmp_path):
    states = small_arcs.states.copy()
    states[0, 0, 0] = 1e182
    path = save_arcs(replace(small_arcs, states=states), tmp_path / "huge.h5")
    with pytest.raises(DatasetError, match="huge.h5: dataset 'states' holds a state component"):
        load_arcs(path)


# ------------------------------------------------------------- 2. identity and consistency
def test_checkpoint_of_another_fit_is_refused(files, tmp_path):
    arcs, _ = files
    out = tmp_path / "lm.h5"
    args = ["fit", str(arcs), "--model", "network", "--hidden", "4", "--solver", "lm"]
    identity = {"solver": "adam", "solver_settings": {"name": "adam", "steps": 30}}
    save_checkpoint(checkpoint_path_for(out), np.zeros(21), {"solver": "adam", "step": 3}, identity)
    _error(
        runner.invoke(app, [*args, "--resume", "-o", str(out)]),
        "belongs to another fit:",
        "solver 'adam' (this command: 'levenberg-marquardt')",
    )
    # a fresh fit does not silently delete the checkpoint
    _error(runner.invoke(app, [*args, "-o", str(out)]), "a checkpoint of an interrupted fit")
    assert checkpoint_path_for(out).exists() and not out.exists()


def test_checkpoint_of_other_arcs_or_steps_is_refused(files, small_arcs, tmp_path, monkeypatch):
    from hamgrav.io import models

    arcs, _ = files
    out = tmp_path / "nn.h5"
    args = ["fit", str(arcs), "--model", "network", "--hidden", "4", "-o", str(out)]
    real_save = models.save_checkpoint

    def save_then_interrupt(*a):
        real_save(*a)
        raise KeyboardInterrupt

    monkeypatch.setattr(models, "save_checkpoint", save_then_interrupt)
    result = runner.invoke(app, [*args, "--steps", "30"])
    assert result.exit_code == 130 and "last checkpoint is kept" in result.output
    monkeypatch.setattr(models, "save_checkpoint", real_save)
    _error(
        runner.invoke(app, [*args, "--steps", "40", "--resume"]),
        "solver_settings.steps 30 (this command: 40)",
    )
    other = save_arcs(small_arcs.subset(range(1, small_arcs.n_arcs)), tmp_path / "other.h5")
    result = runner.invoke(app, [*args[:1], str(other), *args[2:], "--steps", "30", "--resume"])
    _error(result, "belongs to another fit: arcs_sha256")


@pytest.mark.parametrize(
    "change, message",
    [
        ({"m": np.zeros(3)}, "does not fit this run"),
        ({"step": 10**9}, "does not fit this run"),
        ({"step": -5}, "does not fit this run"),
        ({"step": float("inf")}, "cannot be read"),
        ({"best_step": 10**6}, "does not fit this run"),
        ({"history": "not json"}, "cannot be read"),
        ({"rng": "{}"}, "cannot be read"),
    ],
    ids=["moments", "step-huge", "step-negative", "step-inf", "best-step", "history", "rng"],
)
def test_tampered_adam_state_is_refused(files, tmp_path, monkeypatch, change, message):
    from hamgrav.io import models

    arcs, _ = files
    out = tmp_path / "nn.h5"
    args = ["fit", str(arcs), "--model", "network", "--hidden", "4", "--steps", "30"]
    real_save = models.save_checkpoint
    saved = {}

    def save_then_interrupt(path, params, state, identity=None):
        real_save(path, params, state, identity)
        saved.update(path=path, params=params, state=state, identity=identity)
        raise KeyboardInterrupt

    monkeypatch.setattr(models, "save_checkpoint", save_then_interrupt)
    assert runner.invoke(app, [*args, "-o", str(out)]).exit_code == 130
    monkeypatch.setattr(models, "save_checkpoint", real_save)
    # a checkpoint whose container and identity are sound, its Adam state not
    state = {**saved["state"], **change}
    real_save(saved["path"], saved["params"], state, saved["identity"])
    _error(runner.invoke(app, [*args, "--resume", "-o", str(out)]), message, "--resume")
    assert not out.exists()


def test_evaluate_from_another_folder_uses_the_fits_arcs(files, small_arcs, tmp_path, monkeypatch):
    arcs, _ = files
    fit_dir, other_dir = tmp_path / "fit", tmp_path / "elsewhere"
    fit_dir.mkdir()
    other_dir.mkdir()
    (fit_dir / "arcs.h5").write_bytes(arcs.read_bytes())
    monkeypatch.chdir(fit_dir)
    result = runner.invoke(app, ["fit", "arcs.h5", "--model", "sh:2", "-o", "m.h5"])
    assert result.exit_code == 0, result.output
    assert load_model("m.h5").training["arcs_file"] == str(fit_dir / "arcs.h5")
    here = runner.invoke(app, ["evaluate", "m.h5", "--json"])
    assert here.exit_code == 0, here.output
    # another truth lies in the other folder under the same name: not used, and refused
    moved = MasconSet(small_arcs.truth.positions * 1.01, small_arcs.truth.masses)
    save_arcs(replace(small_arcs, truth=moved), other_dir / "arcs.h5")
    monkeypatch.chdir(other_dir)
    there = runner.invoke(app, ["evaluate", str(fit_dir / "m.h5"), "--json"])
    assert there.exit_code == 0, there.output
    assert json.loads(there.stdout)["field_error"] == json.loads(here.stdout)["field_error"]
    _error(
        runner.invoke(app, ["evaluate", str(fit_dir / "m.h5"), "--arcs", "arcs.h5"]),
        "hold another truth than the one model",
    )
    shifted = replace(small_arcs.body, origin_m=(1.0, 0.0, 0.0))
    save_arcs(
        replace(small_arcs, body_origin_m=shifted.origin_m, body=shifted), other_dir / "shifted.h5"
    )
    _error(
        runner.invoke(app, ["evaluate", str(fit_dir / "m.h5"), "--arcs", "shifted.h5"]),
        "in a frame with origin (1.0, 0.0, 0.0) m",
    )


def test_model_without_training_record_warns(files, tmp_path, old_hdf5):
    _, model = files
    old = tmp_path / "old.h5"
    old.write_bytes(model.read_bytes())
    with old_hdf5(old) as f:
        del f.attrs["training"]
    with pytest.warns(HamgravWarning, match="old.h5 has no hamgrav checksum"):
        assert load_model(old).training == {}
    result = runner.invoke(app, ["evaluate", str(old), "--json"])
    assert result.exit_code == 0, result.output
    assert "does not record the truth it was fitted against" in result.output


# ------------------------------------------------------------------------------ 3. outputs
@pytest.mark.parametrize("kind", ["folder", "symlink", "device", "missing-folder"])
def test_outputs_checked_before_the_computation(files, tmp_path, kind):
    arcs, model = files
    target = {
        "folder": tmp_path,
        "symlink": tmp_path / "link.h5",
        "device": tmp_path / "fifo",  # not /dev/null: a broken check would replace it
        "missing-folder": tmp_path / "nope" / "out.h5",
    }[kind]
    if kind == "symlink":
        target.symlink_to(model)
    if kind == "device":
        os.mkfifo(target)
    message = {
        "folder": "is a folder; give a file name",
        "symlink": "is a symbolic link",
        "device": "is not a regular file",
        "missing-folder": "does not exist; create it first",
    }[kind]
    _error(runner.invoke(app, ["fit", str(arcs), "--model", "sh:2", "-o", str(target)]), message)
    pool = tmp_path / "pool.toml"
    pool.write_text('body = "synthetic"\n[orbits]\ncount = 2\n')
    _error(
        runner.invoke(app, ["select", str(model), "--pool", str(pool), "-o", str(target)]), message
    )
    if kind == "symlink":
        assert target.is_symlink() and os.readlink(target) == str(model)
    if kind == "device":
        assert target.is_fifo()


def test_an_output_that_is_an_input_is_refused(files, tmp_path):
    arcs, model = files
    kept = {path: path.read_bytes() for path in (arcs, model)}
    relative = arcs.parent / "x" / ".." / arcs.name  # the same file by another spelling
    _error(
        runner.invoke(app, ["fit", str(arcs), "--model", "sh:2", "-o", str(relative)]),
        "is also the input ARCS",
        "give another output path",
    )
    _error(
        runner.invoke(app, ["export", str(model), "--format", "icgem", "-o", str(model)]),
        "is also the input MODEL",
    )
    pool = tmp_path / "pool.toml"
    pool.write_text('body = "synthetic"\n[orbits]\ncount = 2\n')
    _error(
        runner.invoke(app, ["select", str(model), "--pool", str(pool), "-o", str(pool)]),
        "is also the input --pool",
    )
    _error(
        runner.invoke(
            app, ["export", str(model), "--format", "icgem", "--arcs", str(arcs), "-o", str(arcs)]
        ),
        "is also the input --arcs",
    )
    campaign = tmp_path / "c.toml"
    campaign.write_text('body = "synthetic"\n[orbits]\ncount = 1\n')
    _error(
        runner.invoke(app, ["simulate", str(campaign), "-o", str(campaign)]),
        "is also the input CAMPAIGN",
    )
    assert campaign.read_text().startswith('body = "synthetic"')
    (tmp_path / "oem").mkdir()
    oem = export_oem_by_trajectory(load_arcs(arcs), tmp_path / "oem")[0]
    text = oem.read_text()
    _error(
        runner.invoke(app, ["import-oem", str(oem), "--body", "synthetic", "-o", str(oem)]),
        f"is also the input FILE {oem}",
    )
    assert oem.read_text() == text
    assert {path: path.read_bytes() for path in kept} == kept
    # continuing a model in place is what --init -o MODEL asks for (its stages are kept)
    inplace = tmp_path / "inplace.h5"
    inplace.write_bytes(model.read_bytes())
    args = ["fit", str(arcs), "--model", "sh:2", "--init", str(inplace), "-o", str(inplace)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert [s["stage"] for s in load_model(inplace).stages] == [0, 1]


def test_an_output_below_a_file_is_named(files, tmp_path):
    arcs, _ = files
    afile = tmp_path / "afile"
    afile.write_text("x")
    args = ["fit", str(arcs), "--model", "sh:2", "-o", str(afile / "m.h5")]
    _error(runner.invoke(app, args), f"{afile} is a file, not a folder")


def test_a_checkpoint_that_is_a_link_is_refused_first(files, tmp_path):
    arcs, _ = files
    output = tmp_path / "m.h5"
    elsewhere = save_checkpoint(tmp_path / "elsewhere.npz", np.zeros(3), {})
    kept = elsewhere.read_bytes()
    checkpoint_path_for(output).symlink_to(elsewhere)
    args = ["fit", str(arcs), "--model", "sh:2", "-o", str(output), "--resume"]
    _error(runner.invoke(app, args), "checkpoint", "is a symbolic link")
    link = checkpoint_path_for(output)
    assert link.is_symlink() and os.readlink(link) == str(elsewhere)
    assert not output.exists() and elsewhere.read_bytes() == kept


def test_same_file_means_the_same_directory_entry(tmp_path):
    from hamgrav.files import same_file

    real = tmp_path / "a.h5"
    real.write_bytes(b"x")
    (tmp_path / "link.h5").symlink_to(real)
    os.link(real, tmp_path / "hard.h5")
    assert same_file(tmp_path / "link.h5", real)
    assert same_file(tmp_path / "sub" / ".." / "a.h5", real)
    # replacing one hard link's entry leaves the other: not the same entry
    assert not same_file(tmp_path / "hard.h5", real)
    assert not same_file(tmp_path / "b.h5", real)


def test_an_unwritable_output_folder_is_refused_first(files, tmp_path, monkeypatch):
    # a read-only folder, as os.access reports it (root ignores permission bits)
    arcs, model = files
    blocked = tmp_path / "blocked"
    blocked.mkdir()
    real_access = os.access
    monkeypatch.setattr(
        os,
        "access",
        lambda p, mode: not (Path(p) == blocked and mode & os.W_OK) and real_access(p, mode),
    )
    _error(
        runner.invoke(app, ["fit", str(arcs), "--model", "sh:2", "-o", str(blocked / "m.h5")]),
        f"cannot write in folder {blocked}",
    )
    _error(
        runner.invoke(app, ["export", str(model), "--format", "icgem", "-o", str(blocked / "m")]),
        "cannot write in folder",
    )
    # a folder still to be made inside it: checked on its nearest existing parent
    _error(
        runner.invoke(app, ["experiment", "descent", "-o", str(blocked / "new" / "run")]),
        "cannot write in folder",
    )
    assert list(blocked.iterdir()) == []
    # a folder to be made below a file
    afile = tmp_path / "afile"
    afile.write_text("x")
    campaign = tmp_path / "c.toml"
    campaign.write_text('body = "synthetic"\n[orbits]\ncount = 1\n')
    args = ["simulate", str(campaign), "-o", str(tmp_path / "x.h5"), "--oem", str(afile / "sub")]
    _error(runner.invoke(app, args), f"{afile} is a file, not a folder")
    assert not (tmp_path / "x.h5").exists()


def test_noise_free_arcs_have_no_formal_errors(files, small_arcs, tmp_path):
    _, model = files
    quiet = save_arcs(replace(small_arcs, sigma_r_m=0.0, sigma_v_m_s=0.0), tmp_path / "quiet.h5")
    _error(
        runner.invoke(app, ["evaluate", str(model), "--arcs", str(quiet), "--uncertainty"]),
        f"--uncertainty: arcs {quiet} record no tracking noise",
        "leave out --uncertainty",
    )
    out = tmp_path / "sh2.gfc"
    result = runner.invoke(
        app, ["export", str(model), "--format", "icgem", "--arcs", str(quiet), "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert "no formal errors" in " ".join(result.output.split()) and out.is_file()
    _error(
        runner.invoke(app, ["fit", str(quiet), "--weighted", "-o", str(tmp_path / "w.h5")]),
        f"--weighted: arcs {quiet} record no tracking noise",
        "leave out --weighted",
    )


# ---------------------------------------------------------------- 4. meaningless values
@pytest.mark.parametrize(
    "args, message",
    [
        (["--steps", "0"], "--steps must be an integer >= 1, got 0"),
        (["--steps", "-3"], "--steps must be an integer >= 1, got -3"),
        (["--hidden", "4.7"], "--hidden must be comma-separated integers >= 1, got '4.7'"),
        (["--hidden", "0"], "--hidden must be an integer >= 1, got 0"),
        (["--learning-rate", "-0.1"], "--learning-rate must be a finite number > 0"),
        (["--learning-rate", "inf"], "--learning-rate must be a finite number > 0, got inf"),
        (["--model", "sh:4", "--kaula", "-1e-6"], "--kaula (one weight ALPHA >= 0, or 'cv')"),
        (["--model", "sh:4", "--kaula", "nan"], "must be a finite number >= 0, got nan"),
        (["--seed", "-1"], "--seed must be an integer >= 0"),
        (["--solver", "sgd"], "--solver must be 'adam' or 'lm'"),
        (["--model", "sh:400"], "--model must be one of"),
    ],
)
def test_fit_options_checked_first(files, tmp_path, args, message):
    arcs, _ = files
    out = tmp_path / "m.h5"
    _error(runner.invoke(app, ["fit", str(arcs), *args, "-o", str(out)]), message)
    assert not out.exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--shells", "0"], "--shells (radii r / R_B) must be a finite number >= 1, got 0.0"),
        (["--shells", "-1.2"], "must be a finite number >= 1, got -1.2"),
        (["--shells", ""], "--shells (radii r / R_B) needs at least one number"),
        (["--altitude", "-5000"], "--altitude (metres above the surface) must be a finite"),
        (["--altitude", "nan"], "must be a finite number >= 0, got nan"),
    ],
)
def test_evaluate_options_checked_first(files, args, message):
    _error(runner.invoke(app, ["evaluate", str(files[1]), *args]), message)


@pytest.mark.parametrize(
    "orbits, tracking, message",
    [
        ("count = 2.7", "", "[orbits] count must be an integer in [1, 1000], got 2.7"),
        ("families = [[1000.0, 30.0]]", "", "radius_rb must be a finite number in (1, 20]"),
        ("families = [[0.5, 30.0]]", "", "radius_rb must be a finite number in (1, 20]"),
        ("radius_rb = [2.0, 1.5]", "", "must be a range [low, high] of two numbers"),
        # the range's end as given, not an inner grid value
        (
            "count = 2\nradius_rb = [0.1, 0.2]",
            "",
            "radius_rb must be a finite number in (1, 20], got 0.1",
        ),
        ("count = 2", "velocity_noise_ratio = -0.1", "velocity_noise_ratio must be a finite"),
        ("count = 2", "arcs_per_orbit = 2.5", "arcs_per_orbit must be an integer in [1, 10000]"),
        ("count = 2", "sigma_r_m = nan", "sigma_r_m must be a finite number in [0, 10000]"),
        ("count = 2", "escape_factor = 0.5", "escape_factor must be a finite number in (1, 1000]"),
    ],
)
def test_campaign_values_checked(tmp_path, orbits, tracking, message):
    toml = tmp_path / "c.toml"
    toml.write_text(f'body = "synthetic"\n[orbits]\n{orbits}\n[tracking]\n{tracking}\n')
    _error(runner.invoke(app, ["simulate", str(toml), "-o", str(tmp_path / "a.h5")]), message)
    assert not (tmp_path / "a.h5").exists()


def test_campaign_of_an_unknown_body_refused_before_simulating(tmp_path, monkeypatch):
    (tmp_path / "bodies").mkdir()
    (tmp_path / "bodies" / "catalogue.json").write_text("{}")
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path / "bodies"))
    toml = tmp_path / "c.toml"
    toml.write_text('body = "vesta"\n[orbits]\ncount = 2\n')
    result = runner.invoke(app, ["simulate", str(toml), "-o", str(tmp_path / "a.h5")])
    _error(result, "c.toml: body: unknown body 'vesta'; known: synthetic")
    assert "simulating" not in result.output and not (tmp_path / "a.h5").exists()


def test_more_parameters_than_observations_warns(small_arcs, tmp_path, monkeypatch):
    from hamgrav.fit.adam import Adam

    def stop(*args, **kwargs):  # the warning comes before the solver: no need to run it
        raise KeyboardInterrupt

    monkeypatch.setattr(Adam, "solve", stop)
    few = save_arcs(small_arcs.subset([0]), tmp_path / "one.h5")
    args = ["fit", str(few), "--model", "network", "--steps", "1", "-o", str(tmp_path / "m.h5")]
    # one arc, too few to hold one out: 39 samples (after the anchor) x 6 = 234 scalars
    small = runner.invoke(app, [*args, "--hidden", "8"])  # 49 parameters
    assert small.exit_code == 130 and "observed scalars" not in small.output
    assert "warning: only 1 arc: none held out" in " ".join(small.output.split())
    large = runner.invoke(app, [*args, "--hidden", "64"])  # 321 parameters
    assert large.exit_code == 130
    assert "warning: 321 parameters but only 234 observed scalars in the 1 training arcs" in (
        " ".join(large.output.split())
    )


# ----------------------------------------------------------------------- 5. vague errors
def test_foreign_hdf5_and_folders_named(tmp_path):
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.arange(3)
    _error(
        runner.invoke(app, ["fit", str(foreign), "-o", str(tmp_path / "m.h5")]),
        f"{foreign} is an HDF5 file but not a hamgrav arcs file",
        "pass a file written by 'hamgrav simulate' or 'hamgrav import-oem'",
    )
    _error(
        runner.invoke(app, ["evaluate", str(tmp_path)]), f"{tmp_path} is a folder; pass the model"
    )


def test_bodies_says_why_only_synthetic(tmp_path, monkeypatch):
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path / "nowhere"))
    result = runner.invoke(app, ["bodies"])
    assert result.exit_code == 0 and result.stdout.split() == ["synthetic"]
    assert "warning: body data folder" in result.output and "does not exist" in result.output
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path))
    (tmp_path / "catalogue.json").write_text("{not json")
    result = runner.invoke(app, ["bodies"])
    assert "catalogue.json is not valid JSON" in " ".join(result.output.split())


# ---------------------------------------------------------------------------- 6. interrupts
def test_interrupt_before_the_first_checkpoint_says_so(files, tmp_path, monkeypatch):
    from hamgrav.fit import estimator

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(estimator.GravityEstimator, "fit", interrupted)
    out = tmp_path / "m.h5"
    result = runner.invoke(app, ["fit", str(files[0]), "--model", "sh:2", "-o", str(out)])
    assert result.exit_code == 130
    assert "interrupted before the first checkpoint; nothing was saved" in result.output
    assert not checkpoint_path_for(out).exists() and "Traceback" not in result.output
    monkeypatch.setattr("hamgrav.io.arcs.load_arcs", interrupted)
    result = runner.invoke(app, ["fit", str(files[0]), "--model", "sh:2", "-o", str(out)])
    assert result.exit_code == 130 and "interrupted; no file is left half-written" in result.output


def test_ctrl_c_while_starting_is_held_and_reported(capsys):
    """A Ctrl-C while the libraries load is held (some libraries swallow KeyboardInterrupt
    in their imports) and ends the command in one line with status 130."""
    import signal

    from hamgrav.cli import _DeferInterrupt

    # a shell starts background jobs with SIGINT ignored (and _DeferInterrupt then leaves it
    # so): the test runs with Python's own handler, as an interactive command does
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(SystemExit) as info, _DeferInterrupt():
            try:  # what a library importing its optional dependencies does
                os.kill(os.getpid(), signal.SIGINT)
            except BaseException:
                pass
        assert info.value.code == 130
        assert capsys.readouterr().err == "interrupted while starting; nothing was done\n"
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        with _DeferInterrupt():  # no Ctrl-C: nothing happens
            pass
    finally:
        signal.signal(signal.SIGINT, outer)


def test_signal_between_fit_and_write_keeps_checkpoint(files, tmp_path, monkeypatch):
    """A Ctrl-C after the fit's last checkpoint but before its model is written (a loaded
    machine delivers signals there) says the checkpoint is kept, and --resume finishes."""
    from hamgrav.fit.fitted import FittedModel

    arcs, _ = files
    out = tmp_path / "lm.h5"
    args = ["fit", str(arcs), "--model", "network", "--hidden", "4", "--solver", "lm"]
    real = FittedModel.with_arcs_file

    def interrupt(self, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(FittedModel, "with_arcs_file", interrupt)
    result = runner.invoke(app, [*args, "-o", str(out)])
    assert result.exit_code == 130, result.output
    assert "the last checkpoint is kept" in result.output and "--resume" in result.output
    assert checkpoint_path_for(out).exists() and not out.exists()
    monkeypatch.setattr(FittedModel, "with_arcs_file", real)
    result = runner.invoke(app, [*args, "-o", str(out), "--resume"])
    assert result.exit_code == 0, result.output
    assert out.exists() and not checkpoint_path_for(out).exists()


def test_a_signal_a_library_turned_into_another_error_is_still_a_stop(files, tmp_path, monkeypatch):
    """A Ctrl-C that arrives inside a library call which reports it as an error of its own
    (numpy's structured-array comparison turns it into a TypeError) is the user's stop: the
    checkpoint is kept and said so, not an internal error."""
    import signal

    from hamgrav import cli
    from hamgrav.fit.fitted import FittedModel

    arcs, _ = files
    out = tmp_path / "lm.h5"
    args = ["fit", str(arcs), "--model", "network", "--hidden", "4", "--solver", "lm"]

    def interrupted_inside_a_library(self, *a, **k):
        cli._signalled[:] = [signal.SIGINT]  # as the command's SIGINT handler records it
        raise TypeError("Cannot compare structured arrays unless they have a common dtype")

    monkeypatch.setattr(FittedModel, "with_arcs_file", interrupted_inside_a_library)
    result = runner.invoke(app, [*args, "-o", str(out)])
    assert result.exit_code == 130, result.output
    assert "internal error" not in result.output
    assert "the last checkpoint is kept" in result.output and "--resume" in result.output
    assert checkpoint_path_for(out).exists() and not out.exists()


def test_an_error_without_a_signal_is_still_a_bug(files, tmp_path, monkeypatch):
    from hamgrav.fit.fitted import FittedModel

    arcs, _ = files
    args = ["fit", str(arcs), "--model", "network", "--hidden", "4", "--solver", "lm"]

    def broken(self, *a, **k):
        raise TypeError("a bug")

    monkeypatch.setattr(FittedModel, "with_arcs_file", broken)
    result = runner.invoke(app, [*args, "-o", str(tmp_path / "m.h5")])
    assert result.exit_code == 70 and "internal error" in result.output, result.output


def test_an_interruption_in_an_exceptions_chain_is_found():
    from hamgrav.cli import Terminated, _as_interruption, _signalled

    _signalled.clear()
    try:
        try:
            raise Terminated
        except KeyboardInterrupt as inner:
            raise TypeError("reported by a library") from inner
    except TypeError as exc:
        assert isinstance(_as_interruption(exc), Terminated)
    assert _as_interruption(ValueError("no signal")) is None

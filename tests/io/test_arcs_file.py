import h5py
import numpy as np
import pytest

from hamgrav.core.arcs import NO_TRUTH
from hamgrav.errors import DatasetError, HamgravWarning
from hamgrav.files import atomic_path
from hamgrav.io.arcs import ARCS_FORMAT_VERSION, load_arcs, save_arcs


def test_round_trip_exact(small_arcs, tmp_path):
    path = save_arcs(small_arcs, tmp_path / "arcs.h5")
    back = load_arcs(path)
    for name in ("times", "states", "true_states", "trajectory"):
        assert np.array_equal(getattr(back, name), getattr(small_arcs, name))
    assert np.array_equal(back.truth.positions, small_arcs.truth.positions)
    assert np.array_equal(back.truth.masses, small_arcs.truth.masses)
    for key, value in small_arcs.trajectory_info.items():
        assert np.array_equal(back.trajectory_info[key], value)
    for name in (
        "body_name",
        "gm_m3_s2",
        "spin_period_s",
        "body_origin_m",
        "sigma_r_m",
        "sigma_v_m_s",
        "interior",
        "interior_parameters",
        "seed",
        "trajectory_kind",
    ):
        assert getattr(back, name) == getattr(small_arcs, name), name
    assert list(tmp_path.iterdir()) == [path]  # no temporary left behind


def test_truncated_file(small_arcs, tmp_path):
    path = save_arcs(small_arcs, tmp_path / "arcs.h5")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match="arcs.h5 is truncated, corrupted or was edited"):
        load_arcs(path)


def test_corrupted_bytes(small_arcs, tmp_path):
    path = save_arcs(small_arcs, tmp_path / "arcs.h5")
    data = bytearray(path.read_bytes())
    data[:64] = b"\x00" * 64
    path.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="arcs.h5 is truncated, corrupted"):
        load_arcs(path)


def test_missing_dataset_named(small_arcs, tmp_path, old_hdf5):
    path = save_arcs(small_arcs, tmp_path / "arcs.h5")
    with old_hdf5(path) as f:
        del f["true_states"]
    with pytest.raises(DatasetError, match="dataset 'true_states' is missing"):
        load_arcs(path)


@pytest.mark.parametrize(
    "name, value",
    [("sigma_r_m", "abc"), ("seed", "x"), ("gm_m3_s2", "1e"), ("gm_m3_s2", np.zeros((2, 2, 2)))],
)
def test_non_numeric_attributes_are_named(small_arcs, tmp_path, old_hdf5, name, value):
    path = save_arcs(small_arcs, tmp_path / "a.h5")
    with old_hdf5(path) as f:
        f.attrs[name] = value
    with pytest.raises(DatasetError, match=f"'{name}' must be a") as info:
        load_arcs(path)
    assert "\n" not in str(info.value)  # one line, even for an array


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda m: -m, "positive total mass"),
        (lambda m: np.concatenate([[-0.1 * m.sum()], 1.1 * m[1:]]), "1 negative masses"),
    ],
)
def test_truth_masses_checked(small_arcs, tmp_path, old_hdf5, change, message):
    path = save_arcs(small_arcs, tmp_path / "a.h5")
    with old_hdf5(path) as f:
        masses = f["truth/masses"][()]
        f["truth/masses"][...] = change(masses)
    with pytest.raises(DatasetError, match=message):
        load_arcs(path)


def _replace(f, name, value):
    del f[name]
    f[name] = value


def _repeat_a_time(f):
    times = f["times"][()]
    times[0, 1] = times[0, 0]
    _replace(f, "times", times)


def _one_sample(f):
    for name in ("times", "states", "true_states"):
        _replace(f, name, f[name][()][:, :1])


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda f: f.attrs.__setitem__("format_version", ARCS_FORMAT_VERSION + 1),
            "newer than this hamgrav reads",
        ),
        (lambda f: _replace(f, "trajectory", f["trajectory"][()] + 0.5), "expected integers"),
        (lambda f: f.attrs.__setitem__("interior", NO_TRUTH), "'true_states' holds numbers"),
        (_repeat_a_time, "must increase strictly"),
        (_one_sample, "arcs of >= 2"),
        (lambda f: f["truth/masses"].__setitem__(..., 0.0), "positive total mass"),
        (
            lambda f: f.attrs.__setitem__("body_origin_m", [np.nan, 0.0, 0.0]),
            "'body_origin_m' must be 3 finite numbers",
        ),
    ],
    ids=[
        "newer",
        "float-trajectory",
        "no-truth",
        "repeated-time",
        "one-sample",
        "zero-mass",
        "nan-origin",
    ],
)
def test_unsealed_file_checked(small_arcs, tmp_path, old_hdf5, edit, message):
    """An older (unsealed) file is read only if its contents pass every check."""
    path = save_arcs(small_arcs, tmp_path / "a.h5")
    with old_hdf5(path) as f:
        edit(f)
    with pytest.raises(DatasetError, match=message):
        load_arcs(path)


def test_text_attributes_as_bytes_read_as_text(small_arcs, tmp_path, old_hdf5):
    """Fixed-length byte strings (as other HDF5 writers store text) read back as text."""
    path = save_arcs(small_arcs, tmp_path / "a.h5")
    with old_hdf5(path) as f:
        for name in ("format", "body_name", "interior"):
            f.attrs[name] = np.bytes_(f.attrs[name])
    with pytest.warns(HamgravWarning, match="no hamgrav checksum"):
        back = load_arcs(path)
    assert back.body_name == small_arcs.body_name and type(back.body_name) is str
    assert back.interior == small_arcs.interior


def test_datasets_carry_their_own_checksums(small_arcs, tmp_path):
    """Besides the file checksum, each dataset has HDF5's Fletcher-32 (what an older reader
    or h5py alone can check)."""
    path = save_arcs(small_arcs, tmp_path / "a.h5")
    found = []
    with h5py.File(path, "r") as f:
        f.visititems(
            lambda name, obj: (
                found.append((name, obj.fletcher32))
                if isinstance(obj, h5py.Dataset) and obj.size
                else None
            )
        )
    assert found and all(flag for _, flag in found), found


def test_other_hdf5_file_refused(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "something-else"
    with pytest.raises(DatasetError, match="not a hamgrav arcs file"):
        load_arcs(path)


def test_failed_write_leaves_nothing(tmp_path):
    target = tmp_path / "out.h5"
    with pytest.raises(RuntimeError, match="boom"), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_missing_folder_named(small_arcs, tmp_path):
    with pytest.raises(DatasetError, match="output folder .*nope does not exist"):
        save_arcs(small_arcs, tmp_path / "nope" / "arcs.h5")

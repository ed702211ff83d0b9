import math
from dataclasses import replace

import numpy as np
import pytest
from astropy.time import Time
from oem import OrbitEphemerisMessage

from hamgrav.core.arcs import Arcs
from hamgrav.core.mascons import MasconSet
from hamgrav.io.oem import REF_FRAME, TIME_SYSTEM, export_oem, export_oem_by_trajectory
from hamgrav.units import CanonicalUnits

EPOCH = "2030-01-01T00:00:00"


def make_arcs(n_arcs=3, m=5, trajectory=None, seed=0):
    """Synthetic arcs: arc k starts at canonical time 1.5 k, samples 0.1 apart."""
    rng = np.random.default_rng(seed)
    times = 1.5 * np.arange(n_arcs)[:, None] + 0.1 * np.arange(m)[None, :]
    true = rng.normal(size=(n_arcs, m, 6))
    traj = np.zeros(n_arcs, dtype=int) if trajectory is None else np.asarray(trajectory)
    kinds = int(traj.max()) + 1
    return Arcs(
        times=times,
        states=true + 1e-3 * rng.normal(size=true.shape),
        true_states=true,
        trajectory=traj,
        trajectory_kind=("orbit",) * kinds,
        trajectory_info={},
        body_name="synthetic",
        gm_m3_s2=3.5,
        spin_period_s=43200.0,
        body_origin_m=(1.0, -2.0, 0.5),
        sigma_r_m=0.05,
        sigma_v_m_s=1e-6,
        truth=MasconSet(np.zeros((1, 3)), np.ones(1)),
        interior="uniform",
        seed=11,
    )


def read_back(path):
    oem = OrbitEphemerisMessage.open(path)
    out = []
    for seg in oem:
        states = list(seg.states)
        out.append(
            (
                seg,
                np.array([s.position for s in states]),
                np.array([s.velocity for s in states]),
                [s.epoch for s in states],
            )
        )
    return oem, out


@pytest.mark.parametrize("noisy", [True, False])
def test_round_trip(tmp_path, noisy):
    arcs = make_arcs()
    path = export_oem(arcs, tmp_path / "arcs.oem", epoch=EPOCH, noisy=noisy)
    assert path == tmp_path / "arcs.oem" and path.is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arcs.oem"]  # no temp left

    units = CanonicalUnits(arcs.gm_m3_s2, arcs.spin_period_s)
    pos_m, vel_m_s = units.state_from_canonical(arcs.states if noisy else arcs.true_states)
    t0 = Time(EPOCH, scale="tdb")
    oem, segs = read_back(path)
    assert len(segs) == arcs.n_arcs
    for k, (seg, pos_km, vel_km_s, epochs) in enumerate(segs):
        md = seg.metadata
        assert md["OBJECT_NAME"] == "orbit-0"
        assert md["CENTER_NAME"] == "SYNTHETIC"
        assert md["REF_FRAME"] == REF_FRAME and md["TIME_SYSTEM"] == TIME_SYSTEM
        np.testing.assert_allclose(pos_km * 1e3, pos_m[k], rtol=1e-9, atol=0)
        np.testing.assert_allclose(vel_km_s * 1e3, vel_m_s[k], rtol=1e-9, atol=0)
        elapsed = np.array([(e - t0).sec for e in epochs])
        np.testing.assert_allclose(elapsed, arcs.times[k] * units.time_s, rtol=0, atol=2e-6)
        spacing = np.diff(elapsed)
        np.testing.assert_allclose(spacing, 0.1 * arcs.spin_period_s / (2 * math.pi), atol=2e-6)
        assert md["START_TIME"] == epochs[0] and md["STOP_TIME"] == epochs[-1]

    text = path.read_text()
    lines = text.splitlines()
    assert lines[0].startswith("CCSDS_OEM_VERS")
    assert lines[1].startswith("COMMENT")
    assert "COMMENT velocities are relative to the rotating body-fixed frame" in text
    assert text.count("META_START\nCOMMENT hamgrav arc") == arcs.n_arcs
    assert oem.header["ORIGINATOR"] == "hamgrav"


def test_arcs_are_written_in_time_order(tmp_path):
    arcs = make_arcs()
    shuffled = arcs.subset([2, 0, 1])
    path = export_oem(shuffled, tmp_path / "s.oem")
    _, segs = read_back(path)
    starts = [epochs[0] for _, _, _, epochs in segs]
    assert starts == sorted(starts)
    units = CanonicalUnits(arcs.gm_m3_s2, arcs.spin_period_s)
    pos_m, _ = units.state_from_canonical(arcs.states)
    np.testing.assert_allclose(segs[0][1] * 1e3, pos_m[0], rtol=1e-9)
    assert "META_START\nCOMMENT hamgrav arc 1\n" in path.read_text()  # index in the input


def test_validation(tmp_path):
    arcs = make_arcs()
    missing = tmp_path / "nope"
    with pytest.raises(ValueError, match="nope"):
        export_oem(arcs, missing / "a.oem")
    with pytest.raises(ValueError, match="no arcs"):
        export_oem(arcs.subset(np.array([], dtype=int)), tmp_path / "a.oem")
    with pytest.raises(ValueError, match="2 trajectories"):
        export_oem(make_arcs(trajectory=[0, 1, 1]), tmp_path / "a.oem")
    overlapping = replace(arcs, times=np.tile(arcs.times[:1], (3, 1)))
    with pytest.raises(ValueError, match="overlap"):
        export_oem(overlapping, tmp_path / "a.oem")
    with pytest.raises(ValueError, match="time zone"):
        export_oem(arcs, tmp_path / "a.oem", epoch="2030-01-01T00:00:00+00:00")
    assert list(tmp_path.iterdir()) == []


def test_nan_leaves_no_file(tmp_path):
    # The oem package would happily write and read back "nan", so the exporter rejects it.
    arcs = make_arcs()
    states = arcs.states.copy()
    states[1, 2, 4] = np.nan
    with pytest.raises(ValueError, match="finite"):
        export_oem(replace(arcs, states=states), tmp_path / "a.oem")
    assert list(tmp_path.iterdir()) == []
    export_oem(replace(arcs, states=states), tmp_path / "a.oem", noisy=False)  # truth is fine


def test_failure_while_writing_leaves_nothing_and_keeps_old_file(tmp_path, monkeypatch):
    arcs = make_arcs()
    target = tmp_path / "a.oem"
    target.write_text("previous content")

    def broken_save(self, file_path, **kwargs):
        with open(file_path, "w") as f:
            f.write("CCSDS_OEM_VERS = 2.0\nhalf a fi")
        raise OSError("disk full")

    monkeypatch.setattr(OrbitEphemerisMessage, "save_as", broken_save)
    with pytest.raises(OSError, match="disk full"):
        export_oem(arcs, target)
    assert target.read_text() == "previous content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.oem"]

    target.unlink()
    with pytest.raises(OSError, match="disk full"):
        export_oem(arcs, target)
    assert list(tmp_path.iterdir()) == []


def test_export_by_trajectory(tmp_path):
    arcs = make_arcs(n_arcs=4, trajectory=[0, 0, 1, 1])
    arcs = replace(arcs, times=np.tile(arcs.times[:2], (2, 1)))  # trajectories overlap in time
    paths = export_oem_by_trajectory(arcs, tmp_path, noisy=False)
    assert [p.name for p in paths] == ["orbit-0.oem", "orbit-1.oem"]
    for traj, p in enumerate(paths):
        oem, segs = read_back(p)
        assert len(segs) == 2
        assert {seg.metadata["OBJECT_NAME"] for seg, *_ in segs} == {f"orbit-{traj}"}

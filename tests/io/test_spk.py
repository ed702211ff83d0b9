"""SPICE SPK kernels: hamgrav's type-13 export, and import of kernels written with spiceypy."""

import math
from dataclasses import replace

import numpy as np
import pytest
import spiceypy
from astropy.time import Time

from hamgrav.bodies.rotation import RotationModel
from hamgrav.errors import DatasetError, InputError
from hamgrav.io.arcs import load_arcs, save_arcs
from hamgrav.io.spk import DEFAULT_CENTRE, import_spk, read_spk, write_spk

EPOCH = "2030-01-01T00:00:00"  # write_spk's default canonical time 0 (TDB)
POLE = {"pole_ra_deg": 90.53, "pole_dec_deg": -66.3, "prime_meridian_deg": 37.0}
#: NAIF ID of the synthetic body in the kernels written here (any ID NAIF gives no body).
CENTRE = 3_999_999
TARGETS = [-1000, -1001, -1002]
NOISE = {"sigma_r_m": 0.05, "sigma_v_m_s": 1e-6}


@pytest.fixture(scope="module")
def written(small_arcs, synthetic, tmp_path_factory):
    return write_spk(small_arcs, tmp_path_factory.mktemp("spk") / "arcs.bsp", synthetic)


def assert_same_arcs(back, arcs):
    assert back.times.shape == arcs.times.shape
    np.testing.assert_allclose(back.times, arcs.times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.states, arcs.states, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(back.trajectory, arcs.trajectory)


def test_round_trip_of_own_spk(small_arcs, synthetic, written, tmp_path):
    back = import_spk([written], synthetic, TARGETS)
    assert_same_arcs(back, small_arcs)
    # the frame origin, canonical time 0, noise and rotation come from the comment area
    assert back.body_origin_m == small_arcs.body_origin_m
    assert (back.sigma_r_m, back.sigma_v_m_s) == (small_arcs.sigma_r_m, small_arcs.sigma_v_m_s)
    assert back.trajectory_kind == small_arcs.trajectory_kind
    assert back.config["noise_from"] == "hamgrav comment"
    assert back.config["epoch_tdb"] == EPOCH + ".000000"
    assert back.config["frames"] == ["J2000 + rotation model"]
    assert back.config["rotation"]["pole_dec_deg"] == 90.0  # the default pole: J2000 +Z
    assert not back.has_truth
    # the file is a plain SPK: SPICE sees one target per trajectory about DEFAULT_CENTRE
    assert sorted(spiceypy.spkobj(str(written))) == sorted(TARGETS)
    assert spiceypy.ktotal("ALL") == 0  # nothing left loaded
    # targets by hamgrav's names, and through the arcs file
    again = import_spk([written], synthetic, ["orbit-0", "orbit-1", "orbit-2"])
    assert_same_arcs(load_arcs(save_arcs(again, tmp_path / "arcs.h5")), small_arcs)
    # every target about the body, in hamgrav's order
    assert_same_arcs(import_spk([written], synthetic, "all"), small_arcs)
    with pytest.raises(InputError, match="give it alone"):
        import_spk([written], synthetic, ["all", -1000])
    other = replace(synthetic, naif_id=2025143)  # another centre: no target about it
    with pytest.raises(InputError, match="no trajectory relative to body"):
        import_spk([written], other, "all")
    # one target alone: its arcs
    one = import_spk([written], synthetic, [-1001])
    mine = small_arcs.trajectory == 1
    np.testing.assert_allclose(one.times, small_arcs.times[mine], rtol=0, atol=1e-9)
    np.testing.assert_allclose(one.states, small_arcs.states[mine], rtol=0, atol=1e-9)


def test_true_states_and_a_body_rotation_round_trip(small_arcs, synthetic, tmp_path):
    rotation = RotationModel(**POLE, spin_period_s=synthetic.spin_period_s)
    turning = replace(synthetic, rotation=rotation)
    path = write_spk(small_arcs, tmp_path / "true.bsp", turning, noisy=False)
    back = import_spk([path], turning, TARGETS, **NOISE)
    np.testing.assert_allclose(back.states, small_arcs.true_states, rtol=0, atol=1e-9)
    assert back.config["rotation"]["pole_ra_deg"] == POLE["pole_ra_deg"]
    assert back.config["noise_from"] == "options"
    with pytest.raises(InputError, match="give no noise level"):
        import_spk([path], turning, TARGETS)


def _kepler(n=30, step=300.0, et0=None):
    """States [km, km/s] of a Keplerian orbit 1 km from the synthetic body (conics, not
    hamgrav), every ``step`` seconds from ``et0``."""
    from hamgrav.bodies.catalogue import load_body

    gm_km = load_body("synthetic").gm_m3_s2 * 1e-9
    et0 = (Time(EPOCH, scale="tdb") - Time("2000-01-01T12:00:00", scale="tdb")).sec
    ets = et0 + step * np.arange(n)
    elements = [0.9, 0.1, math.radians(50), 0.3, 1.1, 0.0, et0, gm_km]
    return ets, np.array([spiceypy.conics(elements, t) for t in ets])


def _spk(path, states, ets, *, target=-77, centre=CENTRE, kind=8):
    """An SPK written with spiceypy directly: one type-8 (equal steps) or 13 segment."""
    handle = spiceypy.spkopn(str(path), "test", 0)
    if kind == 8:
        spiceypy.spkw08(
            handle, target, centre, "J2000", ets[0], ets[-1], "test", 7, len(ets), states,
            ets[0], ets[1] - ets[0],
        )  # fmt: skip
    else:
        spiceypy.spkw13(
            handle, target, centre, "J2000", ets[0], ets[-1], "test", 5, len(ets), states, ets
        )
    spiceypy.spkcls(handle)
    return path


def _expected(body, rotation, ets, states):
    """Canonical body-fixed states of J2000 states [km, km/s] at ephemeris times."""
    since = (Time("2000-01-01T12:00:00", scale="tdb") - Time(rotation.epoch, scale="tdb")).sec + ets
    r, _, v = rotation.to_body(since, states[:, :3] * 1e3, states[:, 3:] * 1e3)
    return body.units.state_to_canonical(r, v)


def test_kernel_written_with_spiceypy_in_j2000(synthetic, tmp_path):
    ets, states = _kepler()
    path = _spk(tmp_path / "kepler.bsp", states, ets)
    rotation = RotationModel(**POLE, spin_period_s=synthetic.spin_period_s)
    turning = replace(synthetic, rotation=rotation)
    arcs = import_spk([path], turning, [-77], centre=CENTRE, **NOISE)
    assert arcs.times.shape == (1, 30) and arcs.trajectory_kind == ("tracked",)
    np.testing.assert_allclose(
        arcs.states[0], _expected(synthetic, rotation, ets, states), rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        synthetic.units.from_time(arcs.times[0]), ets - ets[0], rtol=0, atol=1e-6
    )
    # the NAIF ID on the body does as well as --center; a rotation model given wins
    other = RotationModel(10.0, 20.0, 30.0, synthetic.spin_period_s)
    given = import_spk(
        [path], replace(synthetic, naif_id=CENTRE), -77, rotation=other, samples=10, **NOISE
    )
    assert given.times.shape == (3, 10)
    np.testing.assert_allclose(
        given.states.reshape(30, 6), _expected(synthetic, other, ets, states), atol=1e-12
    )
    # sampled at a step: every other sample is a node of the segment
    stepped = read_spk([path], turning, -77, step_s=150.0, centre=CENTRE)
    (epochs, r, v) = stepped.pieces[0]
    assert len(epochs) == 59
    want = _expected(synthetic, rotation, ets, states)
    got = synthetic.units.state_to_canonical(r, v)[::2]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # and a span of it
    part = read_spk(
        [path], turning, -77, start="2030-01-01T00:20:00", stop="2030-01-01T01:00:00",
        centre=CENTRE,
    )  # fmt: skip
    assert len(part.pieces[0][0]) == 9  # 1200 s to 2400 s every 300 s


def _pck(path, code, ra, dec, w0, spin_period_s):
    """A text FK + PCK giving body ``code`` the frame SYNTH_FIXED (IAU angles [deg])."""
    rate = 360.0 * 86400.0 / spin_period_s  # deg/day
    path.write_text(
        "KPL/FK\n\\begindata\n"
        f"FRAME_SYNTH_FIXED = 1999999\nFRAME_1999999_NAME = 'SYNTH_FIXED'\n"
        f"FRAME_1999999_CLASS = 2\nFRAME_1999999_CLASS_ID = {code}\n"
        f"FRAME_1999999_CENTER = {code}\nOBJECT_{code}_FRAME = 'SYNTH_FIXED'\n"
        f"BODY{code}_POLE_RA = ( {ra!r} 0.0 0.0 )\nBODY{code}_POLE_DEC = ( {dec!r} 0.0 0.0 )\n"
        f"BODY{code}_PM = ( {w0!r} {rate!r} 0.0 )\n\\begintext\n"
    )
    return path


def test_kernel_with_a_pck_gives_its_frame(synthetic, tmp_path):
    """SPICE's PCK rotation (IAU angles at J2000) and hamgrav's rotation model of the same
    angles agree: the imported states are the model's body-fixed states."""
    ets, states = _kepler()
    path = _spk(tmp_path / "kepler.bsp", states, ets, kind=13)
    pck = _pck(tmp_path / "synth.tf", CENTRE, 40.0, 25.0, 123.0, synthetic.spin_period_s)
    arcs = import_spk([path, pck], synthetic, [-77], centre=CENTRE, **NOISE)
    assert arcs.config["frames"] == ["SYNTH_FIXED (kernels)"] and arcs.config["rotation"] is None
    rotation = RotationModel(40.0, 25.0, 123.0, synthetic.spin_period_s)
    np.testing.assert_allclose(
        arcs.states[0], _expected(synthetic, rotation, ets, states), rtol=0, atol=1e-9
    )
    # independently of hamgrav's rotation code: SPICE's own state transformation into the
    # frame gives the body-fixed position and the rotating-frame velocity
    spiceypy.furnsh(str(pck))
    try:
        fixed = np.array(
            [
                spiceypy.sxform("J2000", "SYNTH_FIXED", t) @ x
                for t, x in zip(ets, states, strict=True)
            ]
        )
    finally:
        spiceypy.kclear()
    units = synthetic.units
    position, velocity = units.state_from_canonical(arcs.states[0])
    np.testing.assert_allclose(position, fixed[: len(position), :3] * 1e3, rtol=0, atol=1e-6)
    np.testing.assert_allclose(velocity, fixed[: len(position), 3:] * 1e3, rtol=0, atol=1e-9)
    # a frame spinning at another rate is not the body's frame
    fast = _pck(tmp_path / "fast.tf", CENTRE, 40.0, 25.0, 123.0, synthetic.spin_period_s / 2)
    with pytest.raises(InputError, match="frame SYNTH_FIXED of the kernels spins at"):
        import_spk([path, fast], synthetic, [-77], centre=CENTRE, **NOISE)
    assert spiceypy.ktotal("ALL") == 0


def test_errors_name_the_kernels_what_is_missing_and_the_fix(synthetic, written, tmp_path):
    with pytest.raises(InputError, match=r"hold no trajectory of target -5 .*-1000.*--target"):
        import_spk([written], synthetic, [-5])
    ets, states = _kepler()
    sun = _spk(tmp_path / "sun.bsp", states, ets, centre=10)
    with pytest.raises(
        InputError, match=r"relative to 10 \(SUN\), not to body 'synthetic' .*add the body's SPK"
    ):
        import_spk([sun], synthetic, [-77], centre=CENTRE, **NOISE)
    with pytest.raises(InputError, match="has no NAIF ID .*pass --center"):
        import_spk([sun], synthetic, [-77], **NOISE)
    with pytest.raises(InputError, match=r"--stop 2031-01-01 TDB is outside the coverage"):
        import_spk([written], synthetic, TARGETS, start="2030-01-01T01:10", stop="2031-01-01")
    with pytest.raises(InputError, match=r"--start 2030-01-01T00:00:00 TDB is outside"):
        import_spk([written], synthetic, TARGETS, start=EPOCH)
    text = tmp_path / "notes.bsp"
    text.write_text("not a kernel\n")
    with pytest.raises(DatasetError, match="notes.bsp is not a SPICE kernel hamgrav reads"):
        import_spk([text], synthetic, TARGETS)
    with pytest.raises(InputError, match="kernel file not found"):
        import_spk([tmp_path / "none.bsp"], synthetic, TARGETS)
    with pytest.raises(InputError, match="--target 'voyager' is no NAIF ID"):
        import_spk([written], synthetic, ["voyager"])
    with pytest.raises(InputError, match="target -1000 is given twice"):
        import_spk([written], synthetic, [-1000, "orbit-0"])
    other = replace(synthetic, gm_m3_s2=2 * synthetic.gm_m3_s2)
    with pytest.raises(InputError, match="was written by hamgrav for gm_m3_s2"):
        import_spk([written], other, TARGETS)
    with pytest.raises(InputError, match="no body-fixed frame .* no rotation model"):
        import_spk([_spk(tmp_path / "k.bsp", states, ets)], synthetic, -77, centre=CENTRE)
    assert spiceypy.ktotal("ALL") == 0  # cleared after every failure too


def test_write_refuses_what_an_spk_cannot_hold(small_arcs, synthetic, tmp_path):
    out = tmp_path / "a.bsp"
    with pytest.raises(InputError, match="write the SPK with the body they were simulated for"):
        write_spk(small_arcs, out, replace(synthetic, spin_period_s=1.0))
    bad = replace(small_arcs, states=np.full_like(small_arcs.states, np.nan))
    with pytest.raises(InputError, match="states must be finite"):
        write_spk(bad, out, synthetic)
    overlapping = replace(small_arcs, trajectory=np.zeros_like(small_arcs.trajectory))
    with pytest.raises(InputError, match="arcs of trajectory 0 overlap in time"):
        write_spk(overlapping, out, synthetic)
    assert not list(tmp_path.iterdir())  # nothing left behind
    # the centre: the body's NAIF ID, else the one given, else DEFAULT_CENTRE
    path = write_spk(small_arcs, out, synthetic, centre=CENTRE)
    assert read_spk([path], synthetic, -1000).record["centre"] == CENTRE
    path = write_spk(small_arcs, out, replace(synthetic, naif_id=2025143), centre=CENTRE)
    assert read_spk([path], synthetic, -1000, centre=2025143).record["centre"] == 2025143
    assert DEFAULT_CENTRE not in (CENTRE, 2025143)

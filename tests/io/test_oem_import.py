import datetime as dt
import math
import re
import warnings
from dataclasses import replace

import numpy as np
import pytest
from astropy.time import Time, TimeDelta
from oem import CURRENT_VERSION, OrbitEphemerisMessage
from oem.components import EphemerisSegment, HeaderSection, MetaDataSection
from scipy.spatial.transform import Rotation

from hamgrav.bodies.rotation import RotationModel
from hamgrav.errors import DatasetError, HamgravWarning, InputError
from hamgrav.io.arcs import load_arcs, save_arcs
from hamgrav.io.oem import export_oem_by_trajectory
from hamgrav.io.oem_import import import_oem

EPOCH = "2030-01-01T00:00:00"  # export_oem's default canonical time 0 (TDB)
POLE = {"pole_ra_deg": 90.53, "pole_dec_deg": -66.3, "prime_meridian_deg": 37.0}


@pytest.fixture(scope="module")
def exported(small_arcs, tmp_path_factory):
    folder = tmp_path_factory.mktemp("oem")
    return export_oem_by_trajectory(small_arcs, folder)


def assert_same_arcs(back, arcs):
    assert back.times.shape == arcs.times.shape
    np.testing.assert_allclose(back.times, arcs.times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.states, arcs.states, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(back.trajectory, arcs.trajectory)


def test_round_trip_of_own_export(small_arcs, synthetic, exported, tmp_path):
    back = import_oem(exported, synthetic)
    assert_same_arcs(back, small_arcs)
    # the frame, canonical time 0 and the noise come from hamgrav's COMMENT lines
    assert back.body_origin_m == small_arcs.body_origin_m
    assert back.body_name == small_arcs.body_name
    assert (back.gm_m3_s2, back.spin_period_s) == (small_arcs.gm_m3_s2, small_arcs.spin_period_s)
    assert (back.sigma_r_m, back.sigma_v_m_s) == (small_arcs.sigma_r_m, small_arcs.sigma_v_m_s)
    assert back.trajectory_kind == small_arcs.trajectory_kind
    assert back.config["noise_from"] == "hamgrav comments"
    assert back.config["epoch_tdb"] == EPOCH + ".000000"
    assert not back.has_truth and small_arcs.has_truth
    assert np.isnan(back.true_states).all()
    # and through the arcs file
    again = load_arcs(save_arcs(back, tmp_path / "arcs.h5"))
    assert_same_arcs(again, small_arcs)
    assert not again.has_truth


def test_xml_gives_the_same_arcs(small_arcs, synthetic, exported, tmp_path):
    xml = []
    for path in exported:
        out = tmp_path / (path.stem + ".xml")
        OrbitEphemerisMessage.convert(path, out, "xml")
        xml.append(out)
    # XML drops the COMMENT lines: the epoch, origin and noise are given
    back = import_oem(
        xml,
        synthetic,
        epoch=EPOCH,
        sigma_r_m=small_arcs.sigma_r_m,
        sigma_v_m_s=small_arcs.sigma_v_m_s,
        origin_m=small_arcs.body_origin_m,
    )
    assert_same_arcs(back, small_arcs)
    assert back.config["noise_from"] == "options"


def _segment(meta, epochs, pos_km, vel_km_s):
    columns = (*pos_km.T.tolist(), *vel_km_s.T.tolist())
    md = MetaDataSection(
        {
            **meta,
            "START_TIME": epochs[0].strftime("%Y-%m-%dT%H:%M:%S.%f"),
            "STOP_TIME": epochs[-1].strftime("%Y-%m-%dT%H:%M:%S.%f"),
        }
    )
    return EphemerisSegment(md, (tuple(epochs), *map(tuple, columns)))


def _write(path, segments):
    header = HeaderSection(
        {
            "CCSDS_OEM_VERS": CURRENT_VERSION,
            "CREATION_DATE": "2030-01-01T00:00:00",
            "ORIGINATOR": "test",
        }
    )
    OrbitEphemerisMessage(header, segments).save_as(path, file_format="kvn")
    return path


@pytest.mark.filterwarnings("ignore:ERFA function")  # UTC in 2030: leap seconds unknown
def test_inertial_frame_with_rotation_model_gives_the_body_fixed_arcs(
    small_arcs, synthetic, tmp_path
):
    """ICRF states in UTC, written with scipy's rotations (independent of hamgrav's), come
    back as the body-fixed arcs."""
    units = synthetic.units
    rot_epoch = Time("2029-12-31T18:00:00", scale="tdb")
    t0 = Time(EPOCH, scale="tdb")
    omega = units.omega_rad_s
    paths = []
    for traj in range(small_arcs.n_trajectories):
        segments = []
        for k in np.flatnonzero(small_arcs.trajectory == traj):
            seconds = units.from_time(small_arcs.times[k])
            # UTC epochs to the microsecond; the exact TDB seconds they stand for
            utc = (t0 + TimeDelta(seconds, format="sec")).utc
            utc.precision = 6
            utc_text = [str(t) for t in utc.isot]
            tdb = Time(utc_text, scale="utc").tdb
            pos, vel = units.state_from_canonical(small_arcs.states[k])
            w = (
                POLE["prime_meridian_deg"]
                + 360.0 * (tdb - rot_epoch).to_value("s") / synthetic.spin_period_s
            )
            angles = np.stack(
                [
                    np.full(len(w), 90.0 + POLE["pole_ra_deg"]),
                    np.full(len(w), 90.0 - POLE["pole_dec_deg"]),
                    w,
                ],
                axis=1,
            )
            to_inertial = Rotation.from_euler("ZXZ", angles, degrees=True)  # = M^T
            inertial_v = vel + omega * np.stack([-pos[:, 1], pos[:, 0], 0 * pos[:, 0]], axis=1)
            r_i, v_i = to_inertial.apply(pos), to_inertial.apply(inertial_v)
            epochs = [dt.datetime.strptime(s, "%Y-%m-%dT%H:%M:%S.%f") for s in utc_text]
            meta = {
                "OBJECT_NAME": f"orbit-{traj}",
                "OBJECT_ID": f"TEST-{traj}",
                "CENTER_NAME": "SYNTHETIC",
                "REF_FRAME": "ICRF",
                "TIME_SYSTEM": "UTC",
            }
            segments.append(_segment(meta, epochs, r_i / 1e3, v_i / 1e3))
        paths.append(_write(tmp_path / f"icrf-{traj}.oem", segments))

    rotation = RotationModel(**POLE, spin_period_s=synthetic.spin_period_s, epoch=rot_epoch.isot)
    # ERFA's multi-line warnings about UTC in 2030 come out as one line
    with pytest.warns(
        HamgravWarning, match="UTC epochs outside the span whose leap seconds ERFA knows"
    ) as seen:
        back = import_oem(
            paths, synthetic, rotation=rotation, epoch=EPOCH, sigma_r_m=0.05, sigma_v_m_s=1e-6
        )
    assert [w.category for w in seen] == [HamgravWarning]
    assert_same_arcs(back, small_arcs)
    assert back.config["frames"] == ["inertial"]
    assert back.config["rotation"]["pole_dec_deg"] == POLE["pole_dec_deg"]

    with pytest.raises(InputError, match="is inertial and body 'synthetic' has no rotation"):
        import_oem(paths, synthetic, sigma_r_m=0.05, sigma_v_m_s=1e-6)


def test_rotation_model_against_hand_cases():
    # pole at the ICRF north pole with RA -90: M = R3(W); W = W0 + 360 deg per period
    rot = RotationModel(-90.0, 90.0, 30.0, spin_period_s=100.0)
    m = rot.matrix(np.array([0.0, 25.0]))
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(m[0], [[c, s, 0], [-s, c, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(m[1], [[-s, c, 0], [-c, -s, 0], [0, 0, 1]], atol=1e-15)
    # the body's +z is the pole direction, whatever the pole
    rot = RotationModel(40.0, 25.0, 0.0, spin_period_s=100.0)
    pole = np.array(
        [
            math.cos(math.radians(25))
            * np.array([math.cos(math.radians(40)), math.sin(math.radians(40))])
        ]
    )
    pole = np.array([pole[0, 0], pole[0, 1], math.sin(math.radians(25))])
    np.testing.assert_allclose(rot.matrix(np.array([13.0]))[0] @ pole, [0, 0, 1], atol=1e-15)
    # a point at rest in the body frame moves inertially at omega x r
    r_body = np.array([[1.0, 2.0, 3.0]])
    r_i, v_i = rot.to_inertial(np.array([5.0]), r_body, np.zeros((1, 3)))
    r_b, p_b, v_rot = rot.to_body(np.array([5.0]), r_i, v_i)
    np.testing.assert_allclose(r_b, r_body, atol=1e-14)
    np.testing.assert_allclose(v_rot, 0, atol=1e-15)
    np.testing.assert_allclose(p_b, rot.omega_rad_s * np.array([[-2.0, 1.0, 0.0]]), atol=1e-15)


def _gap_file(path, covariance=False, second=10, scale=1.0):
    """An OEM file of one body-fixed run with a 420 s gap, 0.87 km from the synthetic body's
    centre (about 2.9 R_B) times ``scale``."""
    base = dt.datetime(2030, 1, 1)
    steps = [10.0 * k for k in range(10)] + [500.0 + 10.0 * k for k in range(second)]
    epochs = [base + dt.timedelta(seconds=s) for s in steps]
    rng = np.random.default_rng(3)
    pos = scale * (0.5 + 0.01 * rng.normal(size=(len(steps), 3)))
    vel = 1e-5 * rng.normal(size=(len(steps), 3))
    meta = {
        "OBJECT_NAME": "probe",
        "OBJECT_ID": "P-1",
        "CENTER_NAME": "SYNTHETIC",
        "REF_FRAME": "BODY_FIXED",
        "TIME_SYSTEM": "TDB",
    }
    _write(path, [_segment(meta, epochs, pos, vel)])
    if covariance:  # two blocks: position sigma 3 m and 5 m, velocity 1 and 2 mm/s
        text = path.read_text()
        blocks = ["COVARIANCE_START"]
        for k, (sr, sv) in enumerate(((3e-3, 1e-6), (5e-3, 2e-6))):
            rows = []
            for i in range(6):
                rows.append(
                    " ".join(
                        f"{(sr**2 if i < 3 else sv**2) if j == i else 0.0:.6e}"
                        for j in range(i + 1)
                    )
                )
            blocks += [f"EPOCH = 2030-01-01T00:0{k}:00.000000", "COV_REF_FRAME = RTN", *rows]
        blocks.append("COVARIANCE_STOP")
        path.write_text(text.rstrip("\n") + "\n" + "\n".join(blocks) + "\n")
    return path


def test_cut_at_gaps_and_into_samples(synthetic, tmp_path):
    path = _gap_file(tmp_path / "gap.oem")
    arcs = import_oem([path], synthetic, sigma_r_m=1.0, sigma_v_m_s=1e-3)
    assert arcs.times.shape == (2, 10)  # split at the 420 s gap
    assert arcs.trajectory_kind == ("tracked",) and arcs.times[0, 0] == 0.0
    seconds = synthetic.units.from_time(arcs.times)
    # astropy keeps epochs to about 1e-11 s
    np.testing.assert_allclose(np.diff(seconds, axis=1), 10.0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(seconds[1, 0], 500.0, rtol=0, atol=1e-9)
    cut = import_oem([path], synthetic, samples=4, sigma_r_m=1.0, sigma_v_m_s=1e-3)
    assert cut.times.shape == (4, 4) and cut.config["dropped_samples"] == 4
    np.testing.assert_array_equal(cut.states[1], arcs.states[0, 4:8])
    # a larger allowed gap keeps the segment whole
    whole = import_oem([path], synthetic, max_gap_s=600.0, sigma_r_m=1.0, sigma_v_m_s=1e-3)
    assert whole.times.shape == (1, 20)


def test_noise_from_covariance_blocks(synthetic, tmp_path):
    arcs = import_oem([_gap_file(tmp_path / "cov.oem", covariance=True)], synthetic)
    assert arcs.config["noise_from"] == "covariance"
    assert math.isclose(arcs.sigma_r_m, math.sqrt((9 + 25) / 2), rel_tol=1e-12)
    assert math.isclose(arcs.sigma_v_m_s, math.sqrt((1 + 4) / 2) * 1e-3, rel_tol=1e-12)


def test_errors_name_the_problem_and_the_fix(synthetic, exported, tmp_path):
    path = _gap_file(tmp_path / "gap.oem")
    with pytest.raises(InputError, match="give no noise level .* pass --sigma-r"):
        import_oem([path], synthetic)
    uneven = _gap_file(tmp_path / "uneven.oem", second=4)
    with pytest.raises(InputError, match="hold 4 to 10 samples; pass --samples M"):
        import_oem([uneven], synthetic, sigma_r_m=1.0, sigma_v_m_s=1.0)
    with pytest.raises(InputError, match="OEM file not found"):
        import_oem([tmp_path / "none.oem"], synthetic)
    with pytest.raises(InputError, match="is a folder; give the OEM files in it"):
        import_oem([tmp_path], synthetic)
    with pytest.raises(InputError, match="gap.oem is given twice .*give it once"):
        import_oem([path, tmp_path / "." / "gap.oem"], synthetic, sigma_r_m=1.0, sigma_v_m_s=1.0)
    bad = tmp_path / "bad.oem"
    bad.write_text("CCSDS_OEM_VERS = 2.0\nnonsense\n")
    with pytest.raises(DatasetError, match="bad.oem is not a readable CCSDS OEM"):
        import_oem([bad], synthetic)
    other = tmp_path / "other.oem"
    other.write_text(path.read_text().replace("REF_FRAME = BODY_FIXED", "REF_FRAME = RTN"))
    with pytest.raises(InputError, match="REF_FRAME 'RTN' is neither body-fixed"):
        import_oem([other], synthetic, sigma_r_m=1.0, sigma_v_m_s=1.0)
    moon = tmp_path / "moon.oem"
    moon.write_text(path.read_text().replace("CENTER_NAME = SYNTHETIC", "CENTER_NAME = MOON"))
    with pytest.raises(InputError, match="CENTER_NAME 'MOON' is not body 'synthetic'"):
        import_oem([moon], synthetic, sigma_r_m=1.0, sigma_v_m_s=1.0)
    for centre, message in (("SYNTHETIC_BARYCENTER", "is a barycentre"), ("SYNTHETICS", "is not")):
        other = tmp_path / "other-centre.oem"
        other.write_text(
            path.read_text().replace("CENTER_NAME = SYNTHETIC", f"CENTER_NAME = {centre}")
        )
        with pytest.raises(InputError, match=f"CENTER_NAME '{centre}' {message}"):
            import_oem([other], synthetic, sigma_r_m=1.0, sigma_v_m_s=1.0)
    hyphen = tmp_path / "hyphen.oem"
    hyphen.write_text(path.read_text().replace("CENTER_NAME = SYNTHETIC", "CENTER_NAME = SYN-A"))
    renamed = replace(synthetic, name="syn-a")
    assert import_oem([hyphen], renamed, sigma_r_m=1.0, sigma_v_m_s=1.0).body_name == "syn-a"
    designated = tmp_path / "designated.oem"
    designated.write_text(
        path.read_text().replace("CENTER_NAME = SYNTHETIC", "CENTER_NAME = 99 SYNTHETIC")
    )
    assert import_oem([designated], synthetic, sigma_r_m=1.0, sigma_v_m_s=1.0).n_arcs == 2
    with pytest.raises(InputError, match="--samples must be at least 2"):
        import_oem([path], synthetic, samples=1)


def test_a_gap_limit_below_the_sample_step_is_refused(synthetic, tmp_path):
    # samples 10 s apart: at 5 s every sample is its own run, and a lone sample is no arc
    path = _gap_file(tmp_path / "gap.oem")
    with pytest.raises(InputError, match=r"no arc of 2 or more samples .*--max-gap 5 s.*raise"):
        import_oem([path], synthetic, max_gap_s=5.0, sigma_r_m=1.0, sigma_v_m_s=1e-3)


def test_bad_epochs_are_one_line_errors(synthetic, exported):
    with pytest.raises(InputError) as info:
        import_oem(exported, synthetic, epoch="notadate")
    assert "\n" not in str(info.value) and "YYYY-MM-DDTHH:MM:SS" in str(info.value)
    assert str(info.value).startswith("--epoch ('notadate')")
    bad_rotation = RotationModel(**POLE, spin_period_s=synthetic.spin_period_s, epoch="never")
    with pytest.raises(InputError) as info:
        import_oem(exported, synthetic, rotation=bad_rotation)
    assert "\n" not in str(info.value) and str(info.value).startswith("--rotation-epoch ('never')")


def test_noise_names_each_source(small_arcs, synthetic, exported):
    # one level given, the other from hamgrav's COMMENT lines
    back = import_oem(exported, synthetic, sigma_r_m=0.2)
    assert back.sigma_r_m == 0.2 and back.sigma_v_m_s == small_arcs.sigma_v_m_s
    assert back.config["noise_from"] == "--sigma-r and hamgrav comments"


def test_noise_levels_from_the_files_must_be_positive(synthetic, exported, tmp_path):
    path = _gap_file(tmp_path / "cov.oem", covariance=True)
    negative = tmp_path / "negative.oem"
    negative.write_text(path.read_text().replace("9.000000e-06", "-9.000000e-06", 1))
    with pytest.raises(InputError, match="negative.oem: a covariance block has a negative"):
        import_oem([negative], synthetic)
    text = exported[0].read_text()
    assert "sigma_r 0.05 m" in text
    wrong = tmp_path / "wrong.oem"
    wrong.write_text(text.replace("sigma_r 0.05 m", "sigma_r -1 m"))
    with pytest.raises(
        InputError, match=r"hamgrav comments: sigma_r is -1.0 m; .* --sigma-r \[m\]$"
    ):
        import_oem([wrong], synthetic)
    # the level given as an option replaces the file's
    assert import_oem([wrong], synthetic, sigma_r_m=0.1).sigma_r_m == 0.1


def test_noise_free_arcs_round_trip(small_arcs, synthetic, tmp_path):
    quiet = replace(small_arcs, sigma_r_m=0.0, sigma_v_m_s=0.0)
    back = import_oem(export_oem_by_trajectory(quiet, tmp_path), synthetic)
    assert_same_arcs(back, quiet)
    assert (back.sigma_r_m, back.sigma_v_m_s) == (0.0, 0.0)


def test_samples_inside_the_body_or_far_away_point_at_the_units(synthetic, tmp_path):
    # metres read as kilometres the other way: 0.87 m from the centre, inside the body
    inside = _gap_file(tmp_path / "inside.oem", scale=1e-3)
    with pytest.raises(
        DatasetError, match="inside.oem: 20 samples inside the shape of 'synthetic'"
    ):
        import_oem([inside], synthetic, sigma_r_m=1.0, sigma_v_m_s=1e-3)
    far = _gap_file(tmp_path / "far.oem", scale=200.0)  # 173 km: 580 R_B
    with pytest.warns(HamgravWarning, match="closest sample is 5.*Brillouin radii.*units"):
        import_oem([far], synthetic, sigma_r_m=1.0, sigma_v_m_s=1e-3)


def test_samples_on_the_surface_are_tracking(synthetic):
    # touchdowns and ejection points lie on the surface, which the facets only approximate:
    # samples down to 1 % of R_B inside it (or 5 sigma_r if more) are tracking
    from hamgrav.io.oem_import import _check_positions

    mesh = synthetic.mesh
    centres, normals = mesh.triangles_center[::50], mesh.face_normals[::50]
    surface = np.concatenate([mesh.vertices[::25], centres])[None]
    depth = synthetic.brillouin_radius * np.array([0.005, 0.02])

    def check(points, sigma_r=0.0):
        _check_positions(points, ["s.oem"], synthetic, np.zeros(3), sigma_r)

    check(surface)
    check((centres - depth[0] * normals)[None])
    with pytest.raises(DatasetError, match=r"s.oem: \d+ samples inside the shape"):
        check((centres - depth[1] * normals)[None])
    check((centres - depth[1] * normals)[None], sigma_r=depth[1])  # within 5 sigma_r
    check((centres - depth[1] * normals)[None], sigma_r=depth[1] / 4)  # 1.25 depth
    with pytest.raises(DatasetError, match="inside the shape"):  # 5 sigma_r: 0.83 depth
        check((centres - depth[1] * normals)[None], sigma_r=depth[1] / 6)


def test_options_and_files_checked_before_reading(synthetic, tmp_path):
    path = _gap_file(tmp_path / "gap.oem")
    noise = {"sigma_r_m": 1.0, "sigma_v_m_s": 1e-3}
    with pytest.raises(InputError, match="--sigma-r must be a positive number, got 0.0"):
        import_oem([path], synthetic, sigma_r_m=0.0, sigma_v_m_s=1e-3)
    for gap in (0.0, float("nan")):
        with pytest.raises(InputError, match="--max-gap must be a positive number of seconds"):
            import_oem([path], synthetic, max_gap_s=gap, **noise)
    # the same file under another spelling of its path, then through a symbolic link
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.oem").symlink_to(path)
    for again in (tmp_path / "sub" / ".." / "gap.oem", tmp_path / "link.oem"):
        with pytest.raises(InputError, match="is given twice"):
            import_oem([path, again], synthetic, **noise)
    # the body's name must stand as a word, not as the end of another one
    other = tmp_path / "other.oem"
    other.write_text(
        path.read_text().replace("CENTER_NAME = SYNTHETIC", "CENTER_NAME = NOSYNTHETIC")
    )
    with pytest.raises(InputError, match="CENTER_NAME 'NOSYNTHETIC' is not body 'synthetic'"):
        import_oem([other], synthetic, **noise)


def test_epochs_equal_in_time_but_not_in_text_are_refused(synthetic, tmp_path):
    # the oem package orders epochs by their text; 00:00:00 and 00:00:00.000000 are one time
    text = _gap_file(tmp_path / "gap.oem").read_text().splitlines()
    rows = [i for i, line in enumerate(text) if line.startswith("2030-01-01T00:00:")]
    first, second = rows[0], rows[1]
    text[first] = "2030-01-01T00:00:00" + text[first][len("2030-01-01T00:00:00.000000") :]
    text[second] = "2030-01-01T00:00:00.000000" + text[second][len("2030-01-01T00:00:10.000000") :]
    same = tmp_path / "same.oem"
    same.write_text("\n".join(text) + "\n")
    with pytest.raises(DatasetError, match="same.oem: the epochs of a segment do not increase"):
        import_oem([same], synthetic, sigma_r_m=1.0, sigma_v_m_s=1e-3)


def test_noise_levels_from_the_comments_must_be_finite(synthetic, exported, tmp_path):
    wrong = tmp_path / "inf.oem"
    wrong.write_text(exported[0].read_text().replace("sigma_r 0.05 m", "sigma_r inf m"))
    with pytest.raises(InputError, match="sigma_r is inf m"):
        import_oem([wrong], synthetic)


def test_own_export_refused_for_another_body_model(synthetic, exported):
    for key in ("gm_m3_s2", "spin_period_s"):
        other = replace(synthetic, **{key: 2 * getattr(synthetic, key)})
        with pytest.raises(InputError, match=f"was written by hamgrav for {key}"):
            import_oem(exported, other)


def test_far_warning_threshold(synthetic, tmp_path):
    # about 150 R_B: warned; about 90 R_B: not (the threshold is 100 R_B)
    far = _gap_file(tmp_path / "far.oem", scale=52.0)
    with pytest.warns(HamgravWarning, match="Brillouin radii"):
        import_oem([far], synthetic, sigma_r_m=1.0, sigma_v_m_s=1e-3)
    near = _gap_file(tmp_path / "near.oem", scale=31.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", HamgravWarning)
        import_oem([near], synthetic, sigma_r_m=1.0, sigma_v_m_s=1e-3)


def test_oem_centre_as_naif_id_or_spice_name(synthetic, tmp_path):
    """The synthetic body standing in for Itokawa (NAIF ID set): its ID and SPICE's name
    are its CENTER_NAME; another body's are not, nor is its barycentre."""
    stand_in = replace(synthetic, naif_id=2025143)
    noise = {"sigma_r_m": 1.0, "sigma_v_m_s": 1e-3}
    text = _gap_file(tmp_path / "gap.oem").read_text()
    for k, centre in enumerate(("2025143", "ITOKAWA", "SYNTHETIC")):
        path = tmp_path / f"ok-{k}.oem"
        path.write_text(text.replace("CENTER_NAME = SYNTHETIC", f"CENTER_NAME = {centre}"))
        assert import_oem([path], stand_in, **noise).n_arcs == 2
    for k, centre in enumerate(("2000433", "EROS", "1000012", "CHURYUMOV-GERASIMENKO")):
        path = tmp_path / f"other-{k}.oem"
        path.write_text(text.replace("CENTER_NAME = SYNTHETIC", f"CENTER_NAME = {centre}"))
        with pytest.raises(InputError, match=f"CENTER_NAME '{centre}' is not body 'synthetic'"):
            import_oem([path], stand_in, **noise)
        # and without a NAIF ID the synthetic body is none of them
        with pytest.raises(InputError, match="is not body"):
            import_oem([path], synthetic, **noise)
    path = tmp_path / "bary.oem"
    path.write_text(text.replace("CENTER_NAME = SYNTHETIC", "CENTER_NAME = ITOKAWA BARYCENTER"))
    with pytest.raises(InputError, match="is a barycentre"):
        import_oem([path], stand_in, **noise)


# ------------------------------------------------------------- redundant information checked
def _velocities_times(path, out, factor):
    """``path`` with every velocity multiplied by ``factor`` (as if written in other units)."""
    lines = []
    for line in path.read_text().splitlines():
        words = line.split()
        if len(words) == 7 and words[0][:4].isdigit():
            words[4:] = [f"{float(w) * factor:.14e}" for w in words[4:]]
            line = " ".join(words)
        lines.append(line)
    out.write_text("\n".join(lines) + "\n")
    return out


def test_velocities_in_other_units_than_positions_are_refused(synthetic, exported, tmp_path):
    # km positions with m/s velocities: read as km/s, 1000 times the positions' rate of change
    mixed = _velocities_times(exported[1], tmp_path / "mixed.oem", 1e3)
    with pytest.raises(
        DatasetError,
        match=r"mixed.oem: its velocities are 1e\+03 times the rate of change of its positions "
        r".*in different units \(an OEM holds km and km/s\): convert one of them$",
    ):
        import_oem([exported[0], mixed], synthetic)
    slow = _velocities_times(exported[2], tmp_path / "slow.oem", 1e-3)  # m/s read as km/s
    with pytest.raises(DatasetError, match="slow.oem: its velocities are 0.001 times"):
        import_oem([slow], synthetic)
    # tracking noise of 0.05 m on steps of about 0.2 m: the files as written pass
    assert import_oem(exported, synthetic).n_arcs == 9
    # noise that drowns the motion is not judged (the scale is too uncertain)
    noisy = _gap_file(tmp_path / "noisy.oem")
    assert import_oem([noisy], synthetic, sigma_r_m=1.0, sigma_v_m_s=1e-3).n_arcs == 2


def test_covariance_blocks_must_be_positive_definite(synthetic, tmp_path):
    path = _gap_file(tmp_path / "cov.oem", covariance=True)
    text = path.read_text()
    # the second row of the first block: a correlation of x and y of 2
    row = "0.000000e+00 9.000000e-06"
    assert row in text
    bad = tmp_path / "indefinite.oem"
    bad.write_text(text.replace(row, "1.800000e-05 9.000000e-06", 1))
    with pytest.raises(
        InputError,
        match=r"indefinite.oem: covariance block 1 \(EPOCH 2030-01-01.*\) is not positive "
        r"definite \(its correlation matrix has the eigenvalue -1; .*pass --sigma-r",
    ):
        import_oem([bad], synthetic)
    # a correlation within +-1 is a covariance
    fine = tmp_path / "correlated.oem"
    fine.write_text(text.replace(row, "4.500000e-06 9.000000e-06", 1))
    assert import_oem([fine], synthetic).config["noise_from"] == "covariance"


def test_files_of_frames_with_other_origins_are_refused(synthetic, exported, tmp_path):
    text = exported[1].read_text()
    found = re.search(r"origin at \(([^,]*),", text)
    x = float(found.group(1))
    moved = tmp_path / "other-campaign.oem"
    moved.write_text(text.replace(f"origin at ({found.group(1)},", f"origin at ({x + 37.0!r},"))
    with pytest.raises(
        InputError,
        match=r"the files are in frames of different origins \(37 m apart\): .*orbit-0.oem, "
        r".*orbit-2.oem at \(.*\) m; .*other-campaign.oem at \(.*\) m \(mesh frame\); import "
        r"the files of each frame separately$",
    ):
        import_oem([exported[0], moved, exported[2]], synthetic)

import os
import platform
import sys


def _x86_with_avx2() -> bool:
    """Whether this is an x86-64 CPU with AVX2 (the instructions of OpenBLAS's Haswell kernels)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        with open("/proc/cpuinfo") as f:
            return " avx2" in f.read()
    except OSError:
        return False


# The snapshot tests (tests/experiments/snapshot.py) compare every number a tiny experiment
# records to 1e-6, and a few of those fits are ill-conditioned: OpenBLAS's kernels for AVX2
# ('Haswell') and AVX-512 ('SkylakeX') CPUs round differently enough to move them (an SH 8
# fit's error by 1 %, an SH fit's iteration count). One kernel on every x86 machine keeps the
# snapshots comparable. OpenBLAS reads the variable when numpy loads it, so before the import;
# subprocesses (the CLI, Dask workers) inherit it.
if "numpy" not in sys.modules and _x86_with_avx2():
    os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")

import numpy as np
import pytest

from hamgrav.bodies.catalogue import bodies_dir, load_body
from hamgrav.bodies.interiors import build_truth
from hamgrav.sim.tracking import OrbitFamily, TrackingConfig, simulate_orbits


@pytest.fixture(scope="session")
def synthetic():
    return load_body("synthetic")


@pytest.fixture(scope="session")
def synthetic_truth(synthetic):
    return build_truth(synthetic, "head-tail", n_mascons=120, seed=1)


@pytest.fixture(scope="session")
def small_arcs(synthetic_truth):
    families = [OrbitFamily(1.3, 20.0), OrbitFamily(1.6, 75.0), OrbitFamily(2.0, 45.0)]
    tracking = TrackingConfig(arcs_per_orbit=3, window_spin_periods=0.5)
    return simulate_orbits(synthetic_truth, families, tracking, seed=7)


@pytest.fixture(scope="session")
def point_mass_arcs(synthetic_truth):
    """Arcs of a truth that is a point mass: there is nothing to learn but noise."""
    from hamgrav.bodies.interiors import Truth
    from hamgrav.core.mascons import MasconSet

    truth = Truth(synthetic_truth.body, MasconSet(np.zeros((1, 3)), np.ones(1)), "point")
    families = [OrbitFamily(1.4, 20.0), OrbitFamily(1.7, 75.0), OrbitFamily(2.0, 45.0)]
    return simulate_orbits(truth, families, TrackingConfig(arcs_per_orbit=4), seed=2)


def _missing_bodies() -> str | None:
    """Why the catalogue bodies (Itokawa, 67P, Bennu, Eros) cannot be loaded, or None."""
    folder = bodies_dir()
    if (folder / "catalogue.json").is_file():
        return None
    return f"body data folder {folder} missing: set HAMGRAV_BODIES"


def _need_bodies() -> None:
    """Skip the running test when the body data folder is missing, or fail it if
    ``HAMGRAV_REQUIRE_BODIES=1`` (CI: a missing folder must not pass as skips)."""
    reason = _missing_bodies()
    if reason is None:
        return
    if os.environ.get("HAMGRAV_REQUIRE_BODIES") == "1":
        pytest.fail(f"{reason} (HAMGRAV_REQUIRE_BODIES=1)", pytrace=False)
    pytest.skip(reason)


def pytest_collection_modifyitems(items):
    # a test that takes a catalogue fixture needs the folder even if nobody marked it
    for item in items:
        if {"data_folder", "itokawa"} & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.bodies)


def pytest_runtest_setup(item):
    if item.get_closest_marker("bodies") is not None:
        _need_bodies()


@pytest.fixture(scope="session")
def data_folder():
    """The body data folder holding catalogue.json (see :func:`_need_bodies`)."""
    _need_bodies()
    return bodies_dir()


@pytest.fixture(scope="session")
def itokawa(data_folder):
    return load_body("itokawa")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture
def old_hdf5():
    """``with old_hdf5(path) as f``: turn a hamgrav HDF5 file into one as an older hamgrav
    wrote it (no checksum user block, same content) and open it for editing."""
    from contextlib import contextmanager
    from pathlib import Path

    import h5py

    @contextmanager
    def edit(path):
        path = Path(path)
        tmp = path.with_name(path.name + ".old")
        with h5py.File(path, "r") as src, h5py.File(tmp, "w") as dst:
            dst.attrs.update(dict(src.attrs))
            for name in src:
                src.copy(src[name], dst, name=name)
        tmp.replace(path)
        with h5py.File(path, "a") as f:
            yield f

    return edit

"""NAIF IDs and SPICE names of the catalogue bodies, as OEM CENTER_NAME and SPK centres."""

from dataclasses import replace

import pytest

from hamgrav.bodies.catalogue import load_body
from hamgrav.io.naif import body_naif_id, centre_is_body

#: SPICE's IDs and names of the catalogue bodies (67P is CHURYUMOV-GERASIMENKO to SPICE).
NAMES = {
    "itokawa": (2025143, ["2025143", "ITOKAWA", "25143 ITOKAWA"]),
    "67p": (1000012, ["1000012", "CHURYUMOV-GERASIMENKO", "67P/CHURYUMOV-GERASIMENKO"]),
    "bennu": (2101955, ["2101955", "BENNU", "101955 BENNU"]),
    "eros": (2000433, ["2000433", "EROS", "433 EROS"]),
}


@pytest.fixture(scope="module")
def catalogue(data_folder):
    return {name: load_body(name, low_resolution=True) for name in NAMES}


@pytest.mark.bodies
def test_catalogue_bodies_have_their_naif_ids(catalogue):
    for name, (code, _) in NAMES.items():
        assert body_naif_id(catalogue[name]) == code
    assert body_naif_id(load_body("synthetic")) is None
    # a NAIF ID set on the body wins over SPICE's name table
    assert body_naif_id(replace(catalogue["eros"], naif_id=-77)) == -77


@pytest.mark.bodies
def test_centre_names_and_ids_recognised_for_the_right_body_only(catalogue):
    for name, body in catalogue.items():
        for other, (_, centres) in NAMES.items():
            for centre in centres:
                assert centre_is_body(centre, body) == (other == name), (centre, name)
    assert not centre_is_body("MOON", catalogue["eros"])
    assert not centre_is_body("301", catalogue["eros"])

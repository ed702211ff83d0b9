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


def test_free_text_never_names_another_body():
    """A description is not a name: words such as 'near Earth' or 'moon' in it never make the
    Earth, the NEAR spacecraft or the Moon the body (they once gave -93 and 301)."""
    rock = replace(load_body("synthetic"), name="rock-2031", source={"kind": "files"})
    for text in ("small rubble pile near Earth", "a binary asteroid moon", "Earth; Moon"):
        assert body_naif_id(replace(rock, description=text)) is None
        # not even when the body is a catalogue body: a description word counts only when
        # SPICE gives it a comet's or asteroid's ID
        catalogued = replace(rock, description=text, source={"kind": "catalogue"})
        assert body_naif_id(catalogued) is None
    assert not centre_is_body("EARTH", replace(rock, description="near Earth"))
    assert not centre_is_body("399", replace(rock, description="near Earth"))
    # a catalogue description naming a small body still gives its ID
    comet = replace(rock, description="67P/Churyumov-Gerasimenko; a comet", source={})
    assert body_naif_id(comet) == 1000012

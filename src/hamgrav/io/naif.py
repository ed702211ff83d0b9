"""NAIF IDs of bodies: how SPICE kernels and OEM CENTER_NAME lines may name the central body.

A body's NAIF ID is :attr:`Body.naif_id` when set (a body TOML's ``naif_id``); otherwise
SPICE's built-in name table (``bodn2c``, plus any NAIF_BODY_NAME assignments in the kernel
pool) is asked for the body's name and, for catalogue bodies only, for the first clause of
the catalogue description (before ``;``) and each of its words: the catalogue's ``67p`` is
``67P/Churyumov-Gerasimenko`` in its description, and SPICE knows ``CHURYUMOV-GERASIMENKO``
(1000012). A description word counts only when SPICE gives it a small body's ID (comets and
asteroids: :data:`SMALL_BODY_IDS`), so that free text such as "near Earth" never makes the
Earth or the NEAR spacecraft the body. Bare numbers are not asked (SPICE reads ``433`` as no
body, and an asteroid number is not its NAIF ID).
"""

from __future__ import annotations

import re

from ..bodies.catalogue import Body

__all__ = ["SMALL_BODY_IDS", "body_naif_id", "centre_is_body", "naif_name", "naif_code"]

#: NAIF IDs of comets (1000001...) and asteroids (2000001..., and the provisional 3000000...,
#: 5xxxxxxx for satellites of asteroids excluded): the bodies hamgrav is for.
SMALL_BODY_IDS = range(1_000_000, 50_000_000)


def naif_code(name: str) -> int | None:
    """The NAIF ID SPICE gives the name ``name`` (None when SPICE knows no such body)."""
    import spiceypy

    if not name.strip():
        return None
    with spiceypy.no_found_check():
        code, found = spiceypy.bodn2c(name.strip())
    return int(code) if found else None


def naif_name(code: int) -> str | None:
    """SPICE's name of the NAIF ID ``code`` (None when it has none)."""
    import spiceypy

    with spiceypy.no_found_check():
        name, found = spiceypy.bodc2n(int(code))
    return str(name) if found else None


def _description_names(body: Body) -> list[str]:
    """Names a catalogue body's description gives it (see the module docstring)."""
    if body.source.get("kind", "catalogue") != "catalogue":
        return []
    clause = body.description.split(";")[0].strip()
    if not clause:
        return []
    return [clause] + [w for w in re.split(r"[\s/]+", clause) if w and not w.isdecimal()]


def body_naif_id(body: Body) -> int | None:
    """The NAIF ID of ``body`` (see the module docstring), None when neither the body nor
    SPICE knows one."""
    if body.naif_id is not None:
        return int(body.naif_id)
    code = naif_code(body.name)
    if code is not None:
        return code
    for name in _description_names(body):
        code = naif_code(name)
        if code is not None and code in SMALL_BODY_IDS:
            return code
    return None


def centre_is_body(centre: str, body: Body) -> bool:
    """Whether ``centre`` (an OEM CENTER_NAME, a SPICE body name or an integer NAIF ID)
    names ``body``: its name as a word of ``centre`` (``25143 ITOKAWA``,
    ``67P/CHURYUMOV-GERASIMENKO``), its NAIF ID, or a name SPICE resolves to that ID.
    Barycentres are not refused here (the caller names them)."""
    word = rf"(?<![a-z0-9]){re.escape(body.name.lower())}(?![a-z0-9])"
    if re.search(word, centre.lower()):
        return True
    code = body_naif_id(body)
    if code is None:
        return False
    text = centre.strip()
    if re.fullmatch(r"[+-]?\d+", text):
        return int(text) == code
    return naif_code(text) == code

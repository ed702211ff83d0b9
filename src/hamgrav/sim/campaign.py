"""Campaign descriptions (TOML) and their simulation into an ``Arcs`` dataset.

Example::

    body = "itokawa"          # a catalogue name, "synthetic" or a body TOML file (relative to
                              # this file's folder; see hamgrav.bodies.files)
    interior = "head-tail"    # uniform | head-tail | void | anomalies
    n_mascons = 600           # truth mascons
    seed = 1
    frame = "centre-of-mass"  # or "shape": origin at the shape's constant-density centroid
    contrast = 2.0            # head-tail only: density of the head over the rest

    [orbits]                  # either a grid over ranges ...
    count = 16
    radius_rb = [1.2, 2.0]
    inclination_deg = [10, 80]
    # families = [[1.5, 30.0], [1.8, 60.0]]   # ... or explicit (radius R_B, inclination deg)

    [tracking]                # all optional; physical units
    arcs_per_orbit = 7
    samples_per_arc = 40
    cadence_s = 14.0
    window_spin_periods = 1.0
    sigma_r_m = 0.05
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

from ..bodies.catalogue import load_body, resolve_body_spec
from ..bodies.interiors import (
    DEFAULT_TRUTH_MASCONS,
    INTERIORS,
    TRUTH_FRAMES,
    Truth,
    build_truth,
)
from ..core.arcs import MAX_SEED, Arcs
from ..errors import InputError
from ..files import read_toml
from .tracking import (
    OrbitFamily,
    TrackingConfig,
    graze_check_points,
    orbit_grid,
    simulate_orbits,
)

__all__ = ["CampaignError", "Campaign", "load_campaign", "run_campaign", "simulate_campaign"]


class CampaignError(InputError):
    """A campaign description is invalid; the message names the key and the fix."""


_TOP_KEYS = {"body", "interior", "n_mascons", "seed", "frame", "contrast", "orbits", "tracking"}
_ORBIT_KEYS = {"count", "radius_rb", "inclination_deg", "families"}
_TRACKING_KEYS = {f.name for f in fields(TrackingConfig)}


@dataclass(frozen=True)
class Campaign:
    """A tracking campaign: body name, truth interior and mascon count, seed, orbit families
    (radius [R_B], inclination [deg]), tracking settings (physical units), the origin of
    the truth's frame (see :data:`hamgrav.bodies.interiors.TRUTH_FRAMES`) and, for the
    head-tail interior, the head's density over the rest's (``contrast``)."""

    body: str
    interior: str
    n_mascons: int
    seed: int
    families: tuple[OrbitFamily, ...]
    tracking: TrackingConfig
    frame: str = "centre-of-mass"
    contrast: float = 2.0

    @classmethod
    def from_dict(cls, data: dict, source: str = "campaign") -> Campaign:
        """A campaign from plain data (a parsed TOML file); errors name ``source``."""

        def fail(msg: str):
            raise CampaignError(f"{source}: {msg}")

        unknown = set(data) - _TOP_KEYS
        if unknown:
            fail(f"unknown key(s) {sorted(unknown)}; allowed: {sorted(_TOP_KEYS)}")
        if not isinstance(data.get("body"), str) or not data["body"].strip():
            fail("'body' is required (a catalogue name, 'synthetic' or a body TOML file)")
        interior = data.get("interior", "uniform")
        if not isinstance(interior, str) or interior not in INTERIORS:
            fail(f"interior {interior!r} is not one of {', '.join(INTERIORS)}")
        frame = data.get("frame", "centre-of-mass")
        if not isinstance(frame, str) or frame not in TRUTH_FRAMES:
            fail(f"frame {frame!r} is not one of {', '.join(TRUTH_FRAMES)}")
        contrast = data.get("contrast", 2.0)
        if not _is_number(contrast) or not 0 < contrast <= 1e3:
            fail(
                f"contrast must be a positive number (head density over the rest, at most "
                f"1000): {contrast!r}"
            )
        orbits = data.get("orbits")
        if not isinstance(orbits, dict):
            fail("an [orbits] table is required")
        unknown = set(orbits) - _ORBIT_KEYS
        if unknown:
            fail(f"unknown key(s) in [orbits] {sorted(unknown)}; allowed: {sorted(_ORBIT_KEYS)}")
        try:
            if "families" in orbits:
                pairs = orbits["families"]
                if not isinstance(pairs, list) or not pairs or not all(_is_pair(p) for p in pairs):
                    fail(
                        "[orbits] families must be a non-empty list of [radius R_B, "
                        f"inclination deg] pairs of numbers, got {pairs!r}"
                    )
                families = [OrbitFamily(float(r), float(i)) for r, i in pairs]
            else:
                count = orbits.get("count", 16)
                if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= 1000:
                    fail(f"[orbits] count must be an integer in [1, 1000], got {count!r}")
                ranges = {}
                for key, default in (("radius_rb", (1.2, 2.0)), ("inclination_deg", (10, 80))):
                    value = orbits.get(key, list(default))
                    if not _is_pair(value) or value[0] > value[1]:
                        fail(
                            f"[orbits] {key} must be a range [low, high] of two numbers with "
                            f"low <= high, got {value!r}"
                        )
                    ranges[key] = (float(value[0]), float(value[1]))
                # both ends must be valid orbits, whatever values the grid takes between
                # them (the options of an experiment are checked the same way)
                for end in (0, 1):
                    OrbitFamily(ranges["radius_rb"][end], ranges["inclination_deg"][end])
                families = orbit_grid(count, ranges["radius_rb"], ranges["inclination_deg"])
        except CampaignError:
            raise
        except InputError as exc:  # from OrbitFamily / orbit_grid
            fail(f"[orbits]: {exc}")
        tracking = data.get("tracking", {})
        if not isinstance(tracking, dict):
            fail("[tracking] must be a table")
        unknown = set(tracking) - _TRACKING_KEYS
        if unknown:
            fail(
                f"unknown key(s) in [tracking] {sorted(unknown)}; allowed: {sorted(_TRACKING_KEYS)}"
            )
        try:
            tracking_config = TrackingConfig(**tracking)
        except InputError as exc:
            fail(str(exc))
        n_mascons = data.get("n_mascons", DEFAULT_TRUTH_MASCONS)
        if isinstance(n_mascons, bool) or not isinstance(n_mascons, int):
            fail(f"n_mascons must be an integer, got {n_mascons!r}")
        if not 10 <= n_mascons <= MAX_TRUTH_MASCONS:
            fail(f"n_mascons must lie in [10, {MAX_TRUTH_MASCONS}], got {n_mascons}")
        seed = data.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
            fail(
                f"seed must be an integer in [0, 2**63 - 1] (seeds are stored as 64-bit "
                f"integers), got {seed!r}"
            )
        return cls(
            body=str(data["body"]),
            interior=interior,
            n_mascons=n_mascons,
            seed=seed,
            families=tuple(families),
            tracking=tracking_config,
            frame=frame,
            contrast=float(contrast),
        )

    def memory_parts(self) -> dict[str, float]:
        """The largest arrays of its simulation [bytes] (see :mod:`hamgrav.sizing`): checked
        against the memory there is before it starts, since each bound of the campaign can
        hold while their product (orbits x arcs x samples) cannot."""
        from ..sizing import campaign_bytes

        t = self.tracking
        return campaign_bytes(
            len(self.families), t.arcs_per_orbit, t.samples_per_arc, graze_check_points(t)
        )

    def as_dict(self) -> dict:
        """Plain data that :meth:`from_dict` reads back."""
        return {
            "body": self.body,
            "interior": self.interior,
            "n_mascons": self.n_mascons,
            "seed": self.seed,
            "frame": self.frame,
            "contrast": self.contrast,
            "orbits": {"families": [[f.radius_rb, f.inclination_deg] for f in self.families]},
            "tracking": {f.name: getattr(self.tracking, f.name) for f in fields(TrackingConfig)},
        }


#: Most truth mascons a campaign may ask for (the paper's largest truth has a few thousand;
#: every field evaluation costs points x mascons).
MAX_TRUTH_MASCONS = 100_000


def _is_number(value) -> bool:
    """A finite real number that is not a bool (TOML gives int or float)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _is_pair(value) -> bool:
    """A list of two finite numbers."""
    return isinstance(value, list) and len(value) == 2 and all(_is_number(v) for v in value)


def load_campaign(path: str | Path) -> Campaign:
    """Read a campaign TOML file (see the module docstring). A body TOML path in it is
    relative to the campaign file's folder: the campaign holds it absolute, so that it names
    the same file from anywhere (and in the arcs' record of the campaign)."""
    try:
        data = read_toml(path)
    except InputError as exc:
        raise CampaignError(f"campaign {exc}") from None
    if isinstance(data.get("body"), str):
        data["body"] = resolve_body_spec(data["body"], Path(path).parent)
    return Campaign.from_dict(data, source=str(path))


def build_campaign_truth(campaign: Campaign, folder=None) -> Truth:
    """The campaign's truth interior in the campaign's frame (catalogue bodies read from
    ``folder``, default :func:`hamgrav.bodies.catalogue.bodies_dir`)."""
    body = load_body(campaign.body, folder=folder)
    return build_truth(
        body,
        campaign.interior,
        n_mascons=campaign.n_mascons,
        seed=campaign.seed,
        frame=campaign.frame,
        contrast=campaign.contrast,
    )


def run_campaign(campaign: Campaign, progress=None, folder=None) -> tuple[Truth, Arcs]:
    """The campaign's truth (see :func:`build_campaign_truth`) and its simulated tracking;
    ``progress(done, total)`` is called after each orbit."""
    truth = build_campaign_truth(campaign, folder=folder)
    arcs = simulate_orbits(
        truth,
        list(campaign.families),
        campaign.tracking,
        seed=campaign.seed,
        progress=progress,
        config=campaign.as_dict(),
    )
    return truth, arcs


def simulate_campaign(campaign: Campaign, progress=None) -> Arcs:
    """Build the truth and simulate the campaign's tracking (the arcs of :func:`run_campaign`)."""
    return run_campaign(campaign, progress)[1]

"""Campaign descriptions (TOML) and their simulation into an ``Arcs`` dataset.

Example::

    body = "itokawa"          # a catalogue name or "synthetic"
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

from dataclasses import dataclass, fields
from pathlib import Path

from ..bodies.catalogue import load_body
from ..bodies.interiors import (
    DEFAULT_TRUTH_MASCONS,
    INTERIORS,
    TRUTH_FRAMES,
    Truth,
    build_truth,
)
from ..core.arcs import Arcs
from ..errors import InputError
from ..io.files import read_toml
from .tracking import OrbitFamily, TrackingConfig, orbit_grid, simulate_orbits

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
        if "body" not in data:
            fail("'body' is required (a catalogue name or 'synthetic')")
        interior = data.get("interior", "uniform")
        if interior not in INTERIORS:
            fail(f"interior {interior!r} is not one of {', '.join(INTERIORS)}")
        frame = data.get("frame", "centre-of-mass")
        if frame not in TRUTH_FRAMES:
            fail(f"frame {frame!r} is not one of {', '.join(TRUTH_FRAMES)}")
        contrast = data.get("contrast", 2.0)
        if isinstance(contrast, bool) or not isinstance(contrast, int | float) or contrast <= 0:
            fail(f"contrast must be a positive number (head density over the rest): {contrast!r}")
        orbits = data.get("orbits")
        if not isinstance(orbits, dict):
            fail("an [orbits] table is required")
        unknown = set(orbits) - _ORBIT_KEYS
        if unknown:
            fail(f"unknown key(s) in [orbits] {sorted(unknown)}; allowed: {sorted(_ORBIT_KEYS)}")
        try:
            if "families" in orbits:
                families = [OrbitFamily(float(r), float(i)) for r, i in orbits["families"]]
            else:
                families = orbit_grid(
                    int(orbits.get("count", 16)),
                    tuple(map(float, orbits.get("radius_rb", (1.2, 2.0)))),
                    tuple(map(float, orbits.get("inclination_deg", (10.0, 80.0)))),
                )
        except (TypeError, ValueError) as exc:
            fail(f"bad [orbits] entry: {exc}")
        tracking = data.get("tracking", {})
        unknown = set(tracking) - _TRACKING_KEYS
        if unknown:
            fail(
                f"unknown key(s) in [tracking] {sorted(unknown)}; allowed: {sorted(_TRACKING_KEYS)}"
            )
        try:
            tracking_config = TrackingConfig(**tracking)
            n_mascons = int(data.get("n_mascons", DEFAULT_TRUTH_MASCONS))
            seed = int(data.get("seed", 0))
        except (TypeError, ValueError) as exc:
            fail(str(exc))
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


def load_campaign(path: str | Path) -> Campaign:
    """Read a campaign TOML file (see the module docstring)."""
    try:
        data = read_toml(path)
    except InputError as exc:
        raise CampaignError(f"campaign {exc}") from None
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

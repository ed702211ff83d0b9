"""Truth interiors: mascon sets built from a body's mesh.

Every interior starts from the same equal-volume sampling of the shape (a filled voxel grid),
gives each sample a density, and compresses the samples to ``n_mascons`` point masses by
k-means (position = mass-weighted centroid of a cluster, mass = the cluster's mass). Masses
sum to 1 (canonical units: the body's GM). Interiors:

- ``uniform``: constant density.
- ``head-tail``: the smaller lobe ("head", beyond the neck along the long axis) ``contrast``
  times as dense as the rest, total mass fixed.
- ``void``: an off-centre cavity holding ``void_fraction`` of the volume, centred at
  ``void_offset`` of the local surface radius along a seeded direction, total mass fixed.
- ``anomalies``: ``anomaly_count`` dense point masses of ``anomaly_mass_fraction`` of the total
  mass each, buried at ``anomaly_depth_ratio`` of the local surface radius, the background
  rescaled to keep the total.

A :class:`Truth` is an interior together with the body expressed in one frame (when
recentred), so that shape, surface sets and mascons share it: ``frame="centre-of-mass"`` puts
the origin at the interior's centre of mass; ``frame="shape"`` at the constant-density
centroid of the shape (what imaging gives), so an interior whose mass is off that centroid
keeps the offset as a degree-1 part of its perturbing potential, which SH from degree 2
cannot represent.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..core.geometry import grid_inside
from ..core.mascons import MasconSet
from ..core.model import Model
from ..core.terms import MasconTerm
from ..errors import BodyDataError, InputError
from .catalogue import Body

__all__ = [
    "INTERIORS",
    "TRUTH_FRAMES",
    "DEFAULT_TRUTH_MASCONS",
    "Truth",
    "build_truth",
    "head_lobe_mask",
    "volume_samples",
]

INTERIORS = ("uniform", "head-tail", "void", "anomalies")
#: Origins of a recentred truth's frame (see the module docstring).
TRUTH_FRAMES = ("centre-of-mass", "shape")

#: Default number of truth mascons: accurate to well under 1 % of the polyhedron potential at
#: 1.05 R_B and small enough to propagate quickly (the paper's 67P truth has 240).
DEFAULT_TRUTH_MASCONS = 600


@dataclass(frozen=True, eq=False)
class Truth:
    """A truth interior: the mascons and the body, both in the same frame (canonical units).

    ``interior`` names the construction and ``parameters`` records its settings.
    """

    body: Body
    mascons: MasconSet
    interior: str
    parameters: dict = field(default_factory=dict)

    @property
    def model(self) -> Model:
        """The truth as a dynamical model: its one known term is the mascon set."""
        return Model((MasconTerm(self.mascons, "truth"),))


def volume_samples(body: Body, target: int = 120_000) -> np.ndarray:
    """About ``target`` equal-volume points filling the shape (canonical): the centres of the
    cells of a cubic grid that lie inside the surface."""
    pitch = (body.volume / target) ** (1.0 / 3.0)
    return grid_inside(np.asarray(body.mesh.triangles), pitch)


def kmeans_labels(points: np.ndarray, k: int, *, seed: int = 0, iterations: int = 30):
    """Lloyd's k-means with a k-d tree for the assignment step; returns the cluster labels.

    Seeded from a random subset of the points; empty clusters are re-seeded at the point
    farthest from its centre, so exactly ``k`` clusters come back.
    """
    rng = np.random.default_rng(seed)
    centres = points[rng.choice(len(points), size=k, replace=False)]
    labels = np.full(len(points), -1)
    for _ in range(iterations):
        distance, new_labels = cKDTree(centres).query(points)
        if np.array_equal(new_labels, labels):
            break
        labels = new_labels
        counts = np.bincount(labels, minlength=k)
        for i in range(3):
            sums = np.bincount(labels, weights=points[:, i], minlength=k)
            centres[counts > 0, i] = sums[counts > 0] / counts[counts > 0]
        for empty in np.flatnonzero(counts == 0):
            far = int(np.argmax(distance))
            centres[empty] = points[far]
            distance[far] = 0.0
    return labels


def compress(points: np.ndarray, weights: np.ndarray, n_mascons: int, seed: int = 0) -> MasconSet:
    """Compress weighted points to ``n_mascons`` point masses by k-means, masses summing to 1."""
    points = np.asarray(points, dtype=float)
    weights = np.asarray(weights, dtype=float)
    keep = weights > 0
    points, weights = points[keep], weights[keep]
    if n_mascons >= len(points):
        return MasconSet(points, weights / weights.sum())
    labels = kmeans_labels(points, n_mascons, seed=seed)
    mass = np.bincount(labels, weights=weights, minlength=n_mascons)
    moment = np.stack(
        [
            np.bincount(labels, weights=weights * points[:, i], minlength=n_mascons)
            for i in range(3)
        ],
        axis=1,
    )
    used = mass > 0
    positions = moment[used] / mass[used, None]
    return MasconSet(positions, mass[used] / mass.sum())


def _long_axis(points: np.ndarray) -> np.ndarray:
    centred = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(centred[:: max(1, len(points) // 20000)], full_matrices=False)
    return vt[0]


def head_lobe_mask(points: np.ndarray) -> np.ndarray:
    """Which volume samples belong to the smaller lobe of a bilobed shape.

    The neck is the minimum of the cross-section profile along the long axis (searched in the
    central 70 % of the length); the head is the side with less volume.
    """
    axis = _long_axis(points)
    s = (points - points.mean(axis=0)) @ axis
    counts, edges = np.histogram(s, bins=80)
    smooth = np.convolve(counts, np.ones(5) / 5, mode="same")
    lo, hi = int(0.15 * len(smooth)), int(0.85 * len(smooth))
    neck_bin = lo + int(np.argmin(smooth[lo:hi]))
    neck = 0.5 * (edges[neck_bin] + edges[neck_bin + 1])
    beyond = s > neck
    return beyond if beyond.sum() < (~beyond).sum() else ~beyond


def _head_region(body: Body, points: np.ndarray) -> tuple[np.ndarray, str]:
    """The head lobe: taken from the body's reference head/tail mascons when it has them
    (their denser points, matched to ours by nearest neighbour), else from the neck split."""
    files = body.data_files
    if "mascons_head_tail_2x" in files and "mascons" in files:
        contrast_set = _read_mascon_csv(files["mascons_head_tail_2x"])
        uniform_set = _read_mascon_csv(files["mascons"])
        if len(contrast_set) != len(uniform_set):
            raise BodyDataError(
                f"mascon files {files['mascons_head_tail_2x']} and {files['mascons']} must "
                "hold the same mascons (one row each); restore them"
            )
        ratio = contrast_set[:, 3] / uniform_set[:, 3]
        reference_head = ratio > np.sqrt(ratio.min() * ratio.max())
        ref_points = body.units.to_length(contrast_set[:, :3]) - (
            np.asarray(body.origin_m) / body.units.length_m
        )
        _, nearest = cKDTree(ref_points).query(points)
        return reference_head[nearest], f"reference file {files['mascons_head_tail_2x'].name}"
    return head_lobe_mask(points), "neck split along the long axis"


def _read_mascon_csv(path) -> np.ndarray:
    """Columns x_m, y_m, z_m, mass_fraction of a (gzipped) reference mascon file."""
    import gzip

    try:
        # an empty file is refused below, without numpy's own warning about it
        with gzip.open(path, "rt") as fh, warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            data = np.loadtxt(fh, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError, EOFError, UnicodeDecodeError) as exc:
        raise BodyDataError(f"cannot read mascon file {path}: {exc}; restore it") from None
    if data.ndim != 2 or data.shape[1] != 4 or len(data) < 1:
        raise BodyDataError(f"mascon file {path} must have 4 columns x_m,y_m,z_m,mass_fraction")
    if not np.all(np.isfinite(data)):
        raise BodyDataError(f"mascon file {path} holds non-finite values (NaN or inf); restore it")
    if np.any(data[:, 3] <= 0):
        raise BodyDataError(f"mascon file {path} has mass fractions <= 0; restore it")
    return data


def _surface_radius(body: Body, directions: np.ndarray) -> np.ndarray:
    """Distance from the origin to the outermost surface crossing along each unit direction."""
    origins = np.zeros_like(directions)
    locations, index_ray, _ = body.mesh.ray.intersects_location(origins, directions)
    radius = np.zeros(len(directions))
    np.maximum.at(radius, index_ray, np.linalg.norm(locations, axis=1))
    return radius


def build_truth(
    body: Body,
    interior: str = "uniform",
    *,
    n_mascons: int = DEFAULT_TRUTH_MASCONS,
    seed: int = 0,
    recentre: bool = True,
    frame: str = "centre-of-mass",
    contrast: float = 2.0,
    void_fraction: float = 0.18,
    void_offset: float = 0.5,
    anomaly_count: int = 4,
    anomaly_mass_fraction: float = 0.015,
    anomaly_depth_ratio: float = 0.85,
    samples: int = 120_000,
) -> Truth:
    """Build a truth interior for ``body`` (see the module docstring for the interiors).

    ``n_mascons`` point masses (k-means of ``samples`` equal-volume samples of the shape),
    seeded by ``seed``; ``frame`` and ``recentre`` choose the origin. ``contrast``: head over
    tail density (head-tail); ``void_fraction`` of the volume and ``void_offset`` (a fraction
    of the local surface radius) place the cavity (void); ``anomaly_count``,
    ``anomaly_mass_fraction`` (of the total mass, each) and ``anomaly_depth_ratio`` (of the
    local surface radius) place the anomalies. Lengths are canonical; masses sum to 1.
    """
    if interior not in INTERIORS:
        raise InputError(f"unknown interior {interior!r}; choose one of {', '.join(INTERIORS)}")
    if frame not in TRUTH_FRAMES:
        raise InputError(f"unknown frame {frame!r}; choose one of {', '.join(TRUTH_FRAMES)}")
    if n_mascons < 1:
        raise InputError("n_mascons must be at least 1")
    rng = np.random.default_rng(seed)
    points = volume_samples(body, samples)
    weights = np.ones(len(points))
    extra: MasconSet | None = None
    parameters: dict = {"n_mascons": n_mascons, "seed": seed, "volume_samples": len(points)}

    if interior == "head-tail":
        if contrast <= 0:
            raise InputError("contrast must be positive")
        head, definition = _head_region(body, points)
        weights[head] = contrast
        parameters |= {
            "contrast": contrast,
            "head_volume_fraction": float(head.mean()),
            "head_definition": definition,
        }
    elif interior == "void":
        if not 0 < void_fraction < 0.9:
            raise InputError("void_fraction must lie in (0, 0.9)")
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        centre = void_offset * _surface_radius(body, direction[None])[0] * direction
        distance = np.linalg.norm(points - centre, axis=1)
        n_void = int(round(void_fraction * len(points)))
        weights[np.argsort(distance)[:n_void]] = 0.0
        parameters |= {
            "void_fraction": n_void / len(points),
            "void_centre": centre.tolist(),
            "void_offset": void_offset,
        }
    elif interior == "anomalies":
        total_anomaly = anomaly_count * anomaly_mass_fraction
        if not 0 < total_anomaly < 1:
            raise InputError("anomaly_count * anomaly_mass_fraction must lie in (0, 1)")
        positions = []
        while len(positions) < anomaly_count:
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            p = anomaly_depth_ratio * _surface_radius(body, d[None])[0] * d
            if body.mesh.contains(p[None])[0]:
                positions.append(p)
        extra = MasconSet(np.array(positions), np.full(anomaly_count, anomaly_mass_fraction))
        parameters |= {
            "anomaly_count": anomaly_count,
            "anomaly_mass_fraction": anomaly_mass_fraction,
            "anomaly_depth_ratio": anomaly_depth_ratio,
            "anomaly_positions": extra.positions.tolist(),
        }

    n_background = n_mascons - (len(extra) if extra is not None else 0)
    usable = int(np.count_nonzero(weights))
    if usable == 0:
        raise InputError(
            f"the {interior} interior of {body.name} leaves no volume samples to build "
            "mascons from; choose another interior or a smaller void_fraction"
        )
    if usable < n_background:
        # fewer weighted samples than mascons (a cavity empties a fifth of them): on a grid
        # fine enough for twice the mascons, never fewer mascons than asked without a word
        return build_truth(
            body,
            interior,
            n_mascons=n_mascons,
            seed=seed,
            recentre=recentre,
            frame=frame,
            contrast=contrast,
            void_fraction=void_fraction,
            void_offset=void_offset,
            anomaly_count=anomaly_count,
            anomaly_mass_fraction=anomaly_mass_fraction,
            anomaly_depth_ratio=anomaly_depth_ratio,
            samples=int(np.ceil(2.0 * samples * n_background / max(usable, 1))),
        )
    mascons = compress(points, weights, n_background, seed=seed)
    if extra is not None:
        scale = 1.0 - extra.total_mass
        mascons = MasconSet(
            np.concatenate([mascons.positions, extra.positions]),
            np.concatenate([mascons.masses * scale, extra.masses]),
        )
    if recentre:
        if frame == "centre-of-mass":
            origin = mascons.centre_of_mass
        else:
            origin = np.asarray(body.constant_density_centre_of_mass, dtype=float)
        body = body.recentred(origin)
        mascons = mascons.translated(-origin)
        parameters["recentred_by"] = origin.tolist()
        parameters["frame"] = frame
    return Truth(body=body, mascons=mascons, interior=interior, parameters=parameters)

import numpy as np
import pytest

from hamgrav.bodies.evaluation import bin_label, equatorial_grid, radial_bins


def test_radial_bins_split_by_radius_in_brillouin_radii():
    directions = np.random.default_rng(3).normal(size=(300, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    r = np.linspace(0.1, 1.2, 300)
    points = 2.0 * r[:, None] * directions  # R_B = 2
    bins = radial_bins(points, 2.0, (0.25, 0.55, 0.95))
    assert list(bins) == ["0.25-0.55", "0.55-0.95"]
    assert len(bins["0.25-0.55"]) == np.sum((r >= 0.25) & (r < 0.55))
    assert len(bins["0.55-0.95"]) == np.sum((r >= 0.55) & (r < 0.95))
    assert bin_label(0.5, 0.95) == "0.50-0.95"
    with pytest.raises(ValueError, match="increasing"):
        radial_bins(points, 2.0, (0.5, 0.3))


def test_equatorial_grid_masks_the_cross_section(synthetic):
    points, inside = equatorial_grid(synthetic, 1.2, 41)
    assert points.shape == (41 * 41, 3) and np.all(points[:, 2] == 0.0)
    r = np.linalg.norm(points, axis=1)
    # the origin is inside the body, everything beyond the Brillouin sphere outside
    assert inside[np.argmin(r)]
    assert not inside[r > synthetic.brillouin_radius].any()
    assert 0 < inside.sum() < len(points)
    # the image layout: row j holds y_j, x across
    image = points[:, 0].reshape(41, 41)
    assert np.all(np.diff(image, axis=1) > 0)

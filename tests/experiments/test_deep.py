"""The deep-region experiment's pieces: its default campaign and the stage order."""

import numpy as np

from hamgrav.experiments.deep import DeepExperimentConfig, arrival_stages


def test_default_campaign_is_the_papers_grid():
    config = DeepExperimentConfig()
    families = config.campaign(0).families
    assert len(families) == 18 and config.arcs_per_orbit == 7 and config.n_mascons == 240
    assert sorted({f.radius_rb for f in families}) == [1.1, 1.8, 2.5]
    inclinations = sorted({f.inclination_deg for f in families})
    assert len(inclinations) == 6 and inclinations[0] == 10.0 and inclinations[-1] == 80.0


def test_every_stage_spans_the_radii_at_different_inclinations():
    families = DeepExperimentConfig().campaign(0).families
    radius = np.array([f.radius_rb for f in families])
    incl = np.array([f.inclination_deg for f in families])
    stages = arrival_stages(radius, incl, 6)
    assert [len(g) for g in stages] == [3] * 6
    assert sorted(np.concatenate(stages).tolist()) == list(range(18))
    for group in stages:
        assert sorted(radius[group]) == [1.1, 1.8, 2.5]
        assert len(set(incl[group])) == 3
    # the order is fixed: the first stage is 10 deg at 1.1, 38 at 1.8, 66 at 2.5 R_B
    assert list(zip(radius[stages[0]], incl[stages[0]], strict=True)) == [
        (1.1, 10.0),
        (1.8, 38.0),
        (2.5, 66.0),
    ]
    # fewer stages: the same order, split into larger groups
    assert np.array_equal(np.concatenate(arrival_stages(radius, incl, 2)), np.concatenate(stages))

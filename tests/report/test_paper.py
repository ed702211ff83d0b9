"""The paper-comparison renderer: claims as table rows in each layout, and the counts over
repetitions that the verdicts print."""

from __future__ import annotations

import pytest

from hamgrav.report.paper import (
    RANGE_COLUMNS,
    STATEMENT_COLUMNS,
    TARGET_COLUMNS,
    Claim,
    claim_over_draws,
    claims_table,
    count_applicable,
    count_draws,
    with_paper,
)


def test_target_table_leaves_empty_cells_one_space_wide():
    rows = claims_table(
        [Claim("deepest bin", "0.29", "0.46 (0.38-0.55)", "<= 0.29", "0 of 8"), Claim("x", "1")],
        TARGET_COLUMNS,
    )
    assert rows == [
        "| quantity | ours | paper | target | met |",
        "|---|---|---|---|---|",
        "| deepest bin | 0.46 (0.38-0.55) | 0.29 | <= 0.29 | 0 of 8 |",
        "| x | | 1 | | |",
    ]


def test_statement_table_and_range_table_layouts():
    claim = Claim("A/m error", "3.5 %", "2.10%", "<= 3.5 %", "7 of 8", "1.00%-4.00%")
    assert claims_table([claim], STATEMENT_COLUMNS)[2] == "| A/m error | 2.10% | 7 of 8 |"
    assert claims_table([claim], RANGE_COLUMNS)[2] == (
        "| A/m error | 3.5 % | 2.10% | 1.00%-4.00% | 7 of 8 (<= 3.5 %) |"
    )
    assert claims_table([], STATEMENT_COLUMNS) == ["| statement | ours | holds |", "|---|---|---|"]


def test_counts_over_draws():
    assert count_draws([True, False, None, 1]) == "2 of 4"  # a missing value fails
    assert count_applicable([True, None, False]) == "1 of 2"
    assert count_applicable([None, None]) == "-"


@pytest.mark.parametrize(
    ("values", "ours", "spread", "verdict"),
    [
        ([0.2, 0.4, 0.3], "0.300", "0.200-0.400", "2 of 3"),
        ([None, None], "-", "-", "0 of 2"),
    ],
)
def test_claim_over_draws(values, ours, spread, verdict):
    claim = claim_over_draws(
        "q", "0.29", values, "{:.3f}", "<= 0.35", lambda v: v is not None and v <= 0.35
    )
    assert (claim.ours, claim.spread, claim.verdict) == (ours, spread, verdict)


def test_claim_over_draws_tests_another_quantity_when_given():
    claim = claim_over_draws("q", "", [0.5, 0.6], "{:.1f}", "below", bool, [True, False])
    assert claim.verdict == "1 of 2"


def test_with_paper():
    assert with_paper("0.123", 0.11, "{:g}") == "0.123 (0.11)"
    assert with_paper("30/30", "30/30") == "30/30 (30/30)"

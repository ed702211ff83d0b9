"""The paper's statements beside ours: every experiment's comparison table comes from one
renderer (:func:`claims_table`), fed with :class:`Claim` rows that the experiment's report
builds from its paper numbers (data in the experiment's module) and its repetitions."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from .tables import summarise

__all__ = [
    "Claim",
    "claim_over_draws",
    "count_draws",
    "count_applicable",
    "claims_table",
    "with_paper",
    "met",
    "TARGET_COLUMNS",
    "RANGE_COLUMNS",
    "STATEMENT_COLUMNS",
]


@dataclass(frozen=True)
class Claim:
    """One statement of the paper and our figure for it, as table cells (text; "" leaves a
    cell empty).

    Attributes:
        quantity: what is compared (the statement).
        paper: the paper's value, as the paper prints it.
        ours: our value: the median over the repetitions with their min-max in brackets, or
            a composite of several.
        target: the bound a repetition must meet ("<= 0.29"), "" when the paper's value is
            quoted for comparison only.
        verdict: how many repetitions meet it ("n of N"), or "yes" / "no" / "-".
        spread: our min-max alone (for tables that print the median and the range apart).
    """

    quantity: str
    paper: str = ""
    ours: str = ""
    target: str = ""
    verdict: str = ""
    spread: str = ""


def count_draws(verdicts: Iterable) -> str:
    """``n of N``: how many of the per-repetition ``verdicts`` are true (None counts as
    false: a missing value does not meet a bound)."""
    verdicts = list(verdicts)
    return f"{sum(bool(v) for v in verdicts)} of {len(verdicts)}"


def count_applicable(verdicts: Iterable) -> str:
    """``n of N`` over the repetitions whose verdict is not None (a statement that does not
    apply to every repetition); "-" when it applies to none."""
    known = [v for v in verdicts if v is not None]
    return count_draws(known) if known else "-"


def claim_over_draws(
    quantity: str,
    paper: str,
    values: Sequence[float | None],
    fmt: str,
    target: str,
    test: Callable[[float | None], bool],
    tested: Sequence | None = None,
) -> Claim:
    """A :class:`Claim` from per-repetition ``values``: their median as ``ours``, min-max as
    ``spread`` ("-" without values) and the repetitions where ``test`` holds as the
    verdict (``test`` applied to ``tested`` instead of ``values`` when given: a statement
    about another quantity, such as one model below another)."""
    s = summarise(list(values))
    missing = s["median"] is None
    return Claim(
        quantity=quantity,
        paper=paper,
        ours="-" if missing else fmt.format(s["median"]),
        spread="-" if missing else f"{fmt.format(s['min'])}-{fmt.format(s['max'])}",
        target=target,
        verdict=count_draws(test(v) for v in (values if tested is None else tested)),
    )


#: Table layouts: (column header, the cell as a format of the claim's fields).
TARGET_COLUMNS = (
    ("quantity", "{quantity}"),
    ("ours", "{ours}"),
    ("paper", "{paper}"),
    ("target", "{target}"),
    ("met", "{verdict}"),
)
RANGE_COLUMNS = (
    ("quantity", "{quantity}"),
    ("paper", "{paper}"),
    ("ours (median)", "{ours}"),
    ("min-max", "{spread}"),
    ("n of N (target)", "{verdict} ({target})"),
)
STATEMENT_COLUMNS = (("statement", "{quantity}"), ("ours", "{ours}"), ("holds", "{verdict}"))


def claims_table(claims: Iterable[Claim], columns=TARGET_COLUMNS) -> list[str]:
    """The Markdown table of ``claims`` in the layout ``columns`` (see TARGET_COLUMNS):
    header, rule, one row per claim."""
    lines = [_row([header for header, _ in columns]), "|" + "---|" * len(columns)]
    for claim in claims:
        fields = dataclasses.asdict(claim)
        lines.append(_row([cell.format(**fields) for _, cell in columns]))
    return lines


def _row(cells: list[str]) -> str:
    # an empty cell is one space wide, as a hand-written table has it
    return "|" + "|".join(f" {c} " if c else " " for c in cells) + "|"


def with_paper(ours: str, paper, fmt: str = "{}") -> str:
    """A table cell of ours with the paper's value (formatted by ``fmt``) in brackets:
    ``0.123 (0.11)``."""
    return f"{ours} ({fmt.format(paper)})"


def met(ok: bool) -> str:
    """A target's verdict in prose: "met" or "not met"."""
    return "met" if ok else "not met"

"""Every committed ``results/<name>/results.json`` names the command that regenerates it: that
command, parsed by the CLI as it is today, must give the configuration the run recorded. A
changed default that would make a committed command compute something else fails here."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hamgrav import cli

RESULTS = Path(__file__).resolve().parents[2] / "results"
REPORTS = sorted(RESULTS.glob("*/results.json"))
#: Options added after some committed runs, with the value that gives the computation those
#: runs made before the option existed (the truth's head-tail contrast was 2; descents were
#: in the centre-of-mass frame, with no shape prior, no comparison run and no control refit;
#: swarm networks had one harmonic weight, no scan, and a scan kept its lowest held-out cost
#: on one split; SH rows were not chosen by cross-validation; the deep ladder's combined
#: oracle rung was normalised as one set, it ran no Adam row, and a balanced fit weighed its
#: sets alike with 40 LM iterations a member).
BEFORE_THE_OPTION = {
    "contrast": 2.0,
    "frame": "centre-of-mass",
    "prior": "none",
    "compare_with": "",
    "harmonic_scan": [],
    "harmonic_scan_rule": "lowest",
    "harmonic_scan_folds": 0,
    "cv_sh": False,
    "oracle_balance": False,
    "adam_rungs": [],
    "adam_steps": 1500,
    "cv_group": "arc",
    "oracle_deep_share": 0.5,
    "oracle_iterations": 40,
    "descent_control": False,
    "descent_share": 0.0,
    "descent_validation": 0.0,
    "descent_anchor": 0.0,
    "descent_anchor_clearance_rb": 0.1,
    "descent_anchor_on": "acceleration",
    "network_start": "random",
    "envelope_softening_rb": 0.0,
    "descent_noise": 1.0,
    "prior_placement": "centred",
}


def test_results_are_found():
    assert len(REPORTS) >= 10, f"expected the committed results under {RESULTS}"


@pytest.mark.parametrize("path", REPORTS, ids=lambda p: p.parent.name)
def test_committed_command_gives_the_recorded_config(path, monkeypatch):
    report = json.loads(path.read_text())
    seen = {}

    def capture(experiment, config, **runner):
        seen.update(experiment=experiment.name, config=config.as_dict(), **runner)
        return {"wall_s": 0.0}, {}

    monkeypatch.setattr(cli, "_run_and_report", capture)
    words = shlex.split(report["command"])
    assert words[:3] == ["hamgrav", "experiment", report["experiment"]]
    result = CliRunner().invoke(cli.app, words[1:])
    assert result.exit_code == 0, result.output
    assert seen["experiment"] == report["experiment"]
    assert Path(seen["output"]) == Path("results") / path.parent.name
    assert seen["seed"] == report["seeds"][0]
    assert (seen["repeat"] or 1) == len(report["seeds"])
    recorded = {**BEFORE_THE_OPTION, **report["config"]}
    differing = {
        key: (recorded.get(key, "<not recorded>"), value)
        for key, value in seen["config"].items()
        if recorded.get(key, "<not recorded>") != value
    }
    assert not differing, f"{path}: recorded vs the command's config: {differing}"
    gone = set(report["config"]) - set(seen["config"])
    assert not gone, f"{path}: recorded options the experiment no longer has: {sorted(gone)}"


@pytest.mark.parametrize("path", REPORTS, ids=lambda p: p.parent.name)
def test_committed_readme_renders_from_its_results(path):
    # a change of the report code that moves a committed README's text must regenerate it
    # (hamgrav experiment readme) and commit it with the reason, never drift silently
    from hamgrav.experiments.registry import get_experiment
    from hamgrav.experiments.runner import read_report, readme_lines

    folder = path.parent
    report = read_report(folder)
    report.setdefault("figures", sorted(p.name for p in folder.glob("*.png")))
    lines = readme_lines(get_experiment(report["experiment"]), report, folder)
    rendered = "\n".join(lines).rstrip("\n") + "\n"
    assert rendered == (folder / "README.md").read_text(), (
        f"{folder}/README.md differs from its rendering: run hamgrav experiment readme {folder}"
    )

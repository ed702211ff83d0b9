"""Inputs whose redundant information contradicts itself get one line naming the cause (status
2), before they are used: OEM velocities in other units than the positions, covariance blocks
that are no covariance, OEM files of two frames in one import, shells beyond the reach of
float64, and hand-edited results.json files."""

import json
import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hamgrav.cli import app
from hamgrav.experiments.schema import REPORT, problem
from hamgrav.io.arcs import save_arcs
from hamgrav.io.oem import export_oem_by_trajectory

runner = CliRunner()
RESULTS = Path(__file__).resolve().parents[1] / "results"


def _error(result, *needles):
    """The run failed as a user error: status 2, one 'error:' line holding every needle."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    text = " ".join(result.output.split())
    assert text.startswith("error:") and "error:" not in text[6:], result.output
    for needle in needles:
        assert needle in text, (needle, text)
    return text


@pytest.fixture(scope="module")
def oem_files(small_arcs, tmp_path_factory):
    return export_oem_by_trajectory(small_arcs, tmp_path_factory.mktemp("oem"))


def _import(files, tmp_path, *options):
    out = tmp_path / "imported.h5"
    args = ["import-oem", *map(str, files), "--body", "synthetic", "-o", str(out), *options]
    return runner.invoke(app, args), out


def test_km_positions_with_m_s_velocities_are_refused(oem_files, tmp_path):
    lines = []
    for line in oem_files[1].read_text().splitlines():
        words = line.split()
        if len(words) == 7 and words[0][:4].isdigit():  # m/s written where km/s belong
            words[4:] = [f"{float(w) * 1e3:.14e}" for w in words[4:]]
        lines.append(" ".join(words) if len(words) == 7 else line)
    mixed = tmp_path / "mixed.oem"
    mixed.write_text("\n".join(lines) + "\n")
    result, out = _import([oem_files[0], mixed], tmp_path)
    _error(
        result,
        "mixed.oem: its velocities are 1e+03 times the rate of change of its positions",
        "positions and velocities are in different units (an OEM holds km and km/s)",
    )
    assert not out.exists()


def test_a_covariance_that_is_no_covariance_is_refused(oem_files, tmp_path):
    block = ["COVARIANCE_START", "EPOCH = 2030-01-01T01:00:00.000000", "COV_REF_FRAME = RTN"]
    for i in range(6):  # variances 1e-6 km^2, and a correlation of 3 between y and x
        block.append(
            " ".join(
                "1.0e-06" if i == j else "3.0e-06" if (i, j) == (1, 0) else "0"
                for j in range(i + 1)
            )
        )
    block.append("COVARIANCE_STOP")
    text = oem_files[0].read_text()
    first = text[: text.index("META_START", text.index("META_STOP"))]  # its first arc alone
    copy = tmp_path / "orbit-0.oem"
    copy.write_text(first.rstrip("\n") + "\n" + "\n".join(block) + "\n")
    result, out = _import([copy], tmp_path)
    _error(
        result,
        "orbit-0.oem: covariance block 1 (EPOCH 2030-01-01T01:00:00",
        "is not positive definite (its correlation matrix has the eigenvalue -2",
        "fix the file, or pass --sigma-r [m] and --sigma-v [m/s]",
    )
    assert not out.exists()


def test_files_of_two_campaigns_are_not_put_in_one_frame(oem_files, tmp_path):
    text = oem_files[2].read_text()
    x = re.search(r"origin at \(([^,]*),", text).group(1)
    moved = tmp_path / "campaign-b.oem"
    moved.write_text(text.replace(f"origin at ({x},", f"origin at ({float(x) + 37.0!r},"))
    result, out = _import([oem_files[0], oem_files[1], moved], tmp_path)
    _error(
        result,
        "the files are in frames of different origins (37 m apart):",
        "orbit-1.oem at (",
        "campaign-b.oem at (",
        "import the files of each frame separately",
    )
    assert not out.exists()


def test_shells_beyond_float64_are_refused_not_blamed_on_the_model(small_arcs, tmp_path):
    arcs = save_arcs(small_arcs, tmp_path / "arcs.h5")
    model = tmp_path / "sh2.h5"
    assert (
        runner.invoke(app, ["fit", str(arcs), "--model", "sh:2", "-o", str(model)]).exit_code == 0
    )
    result = runner.invoke(app, ["evaluate", str(model), "--shells", "1.05,1e300"])
    text = _error(result, "--shells (radii r / R_B) must be at most 1000, got 1e+300")
    assert "fit it again" not in text
    result = runner.invoke(app, ["evaluate", str(model), "--shells", "1000", "--json"])
    assert result.exit_code == 0 and '"r1000"' in result.output


# ------------------------------------------------------------------------------ results.json
def _results(tmp_path, name, edit):
    """A copy of the committed results folder ``name`` with its results.json edited."""
    folder = tmp_path / name
    folder.mkdir()
    report = json.loads((RESULTS / name / "results.json").read_text())
    edit(report)
    (folder / "results.json").write_text(json.dumps(report))
    return folder


def test_the_committed_results_follow_the_schema():
    for path in sorted(RESULTS.glob("*/results.json")):
        assert problem(json.loads(path.read_text()), REPORT) is None, path


def _drop_arcs(r):
    del r["repetitions"][0]["n_arcs"]


def _null_table(r):
    r["aggregate"]["field_error"] = None


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda r: r.pop("seeds"), "$.seeds is missing"),
        (lambda r: r.update(seeds=[]), "$.seeds must not be empty"),
        (lambda r: r.update(wall_s="long"), "$.wall_s must be a number, got 'long'"),
        (lambda r: r.update(repetitions={}), "$.repetitions must be a list, got {}"),
        (_drop_arcs, "$.repetitions[0].n_arcs is missing"),
        (_null_table, "$.aggregate.field_error holds a value of another kind than expected"),
    ],
)
def test_a_hand_edited_results_file_names_the_json_path(tmp_path, edit, message):
    folder = _results(tmp_path, "descent-itokawa-extended", edit)
    (folder / "README.md").write_text("before")
    result = runner.invoke(app, ["experiment", "readme", str(folder)])
    _error(result, "results.json: " + message, "restore the file (or run the experiment again)")
    assert (folder / "README.md").read_text() == "before"  # the old README is kept


def test_readme_of_an_unedited_copy_is_the_committed_one(tmp_path):
    folder = tmp_path / "descent-itokawa-extended"
    shutil.copytree(RESULTS / folder.name, folder)
    assert runner.invoke(app, ["experiment", "readme", str(folder)]).exit_code == 0
    assert (folder / "README.md").read_text() == (RESULTS / folder.name / "README.md").read_text()


def test_compare_with_a_hand_edited_run_names_the_json_path(tmp_path):
    def total_as_text(r):
        r["repetitions"][0]["models"]["point-mass"]["total"] = "12"

    other = _results(tmp_path, "descent-itokawa-extended", total_as_text)
    args = ["experiment", "descent", "--compare-with", str(other), "-o", str(tmp_path / "o")]
    _error(
        runner.invoke(app, args),
        "--compare-with:",
        "results.json: $.repetitions[0].models.point-mass.total must be an integer, got '12'",
    )
    (other / "results.json").write_text("[1, 2]")
    _error(runner.invoke(app, args), "results.json: $ must be an object, got [1, 2]")

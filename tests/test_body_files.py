"""A body TOML wherever a body's name is taken: hamgrav body, simulate (campaign files),
import-oem --body, the experiment runner's check and the swarm experiment's body."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from hamgrav.bodies.catalogue import contact_binary, load_body
from hamgrav.bodies.shapes import write_pds_plates
from hamgrav.cli import app
from hamgrav.errors import BodyDataError
from hamgrav.io.arcs import load_arcs
from hamgrav.io.oem import export_oem_by_trajectory
from hamgrav.sim.campaign import load_campaign

runner = CliRunner()
SYNTHETIC = contact_binary()


def synthetic_toml(folder, units="m", name="synthetic", exact=False):
    """The synthetic body as a user's files: its shape as a plate table (``exact``: as an OBJ
    file holding every float's 17 digits, in metres), its constants in a body TOML beside it."""
    folder.mkdir(parents=True, exist_ok=True)
    shape = "shape.obj" if exact else "shape.tab"
    if exact:
        mesh = SYNTHETIC.mesh_m
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces.tolist()]
        (folder / shape).write_text("\n".join(lines) + "\n")
        units = "m"
    else:
        write_pds_plates(folder / shape, SYNTHETIC.mesh_m, units=units)
    path = folder / "body.toml"
    path.write_text(
        f'name = "{name}"\nshape = "{shape}"\nunits = "{units}"\n'
        f"gm_m3_s2 = {SYNTHETIC.gm_m3_s2!r}\nspin_period_s = {SYNTHETIC.spin_period_s!r}\n"
        f"description = {json.dumps(SYNTHETIC.description)}\n"
    )
    return path


def test_body_command_reports_a_body_toml_as_the_catalogue_body(tmp_path):
    # the same shape to the last bit: the same truth, the same figures
    path = synthetic_toml(tmp_path, exact=True)
    assert load_body(str(path)).mesh_sha256 == load_body("synthetic").mesh_sha256
    by_name = runner.invoke(app, ["body", "synthetic", "--mascons", "200"])
    by_file = runner.invoke(app, ["body", str(path), "--mascons", "200"])
    assert by_name.exit_code == 0 and by_file.exit_code == 0, by_file.output
    assert "GM [m^3/s^2]" in by_file.stdout and by_file.stdout == by_name.stdout


def test_body_command_refuses_a_bad_body_toml_in_one_line(tmp_path):
    path = synthetic_toml(tmp_path, units="m")
    path.write_text(path.read_text().replace('units = "m"', 'units = "km"'))
    result = runner.invoke(app, ["body", str(path)])
    assert result.exit_code == 2
    message = " ".join(result.output.split())
    assert message.startswith("error: body file") and 'set units = "m"' in message


CAMPAIGN = """
body = "rock/body.toml"
interior = "uniform"
n_mascons = 100
seed = 5
[orbits]
families = [[1.5, 30.0], [1.9, 70.0]]
[tracking]
arcs_per_orbit = 2
window_spin_periods = 0.3
"""


def test_campaign_body_toml_is_relative_to_the_campaign_file(tmp_path, monkeypatch):
    body = synthetic_toml(tmp_path / "campaigns" / "rock")
    campaign = tmp_path / "campaigns" / "c.toml"
    campaign.write_text(CAMPAIGN)
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert load_campaign(campaign).body == str(body.resolve())
    out = tmp_path / "arcs.h5"
    result = runner.invoke(app, ["simulate", str(campaign), "-o", str(out)])
    assert result.exit_code == 0, result.output
    arcs = load_arcs(out)
    assert arcs.n_arcs == 4 and arcs.body_name == "synthetic"
    assert arcs.config["body"] == str(body.resolve())
    assert arcs.gm_m3_s2 == SYNTHETIC.gm_m3_s2
    # a campaign naming a missing body file is refused before anything is simulated
    campaign.write_text(CAMPAIGN.replace("rock/body.toml", "rock/nothing.toml"))
    result = runner.invoke(app, ["simulate", str(campaign), "-o", str(tmp_path / "b.h5")])
    assert result.exit_code == 2 and "body file not found" in result.output
    assert not (tmp_path / "b.h5").exists()


def test_import_oem_body_toml(small_arcs, tmp_path):
    path = synthetic_toml(tmp_path / "body")
    files = export_oem_by_trajectory(small_arcs, tmp_path)
    out = tmp_path / "arcs.h5"
    result = runner.invoke(
        app, ["import-oem", *map(str, files), "--body", str(path), "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    arcs = load_arcs(out)
    np.testing.assert_allclose(arcs.states, small_arcs.states, rtol=0, atol=1e-9)


class _Stop(Exception):
    """Raised by a stand-in to end a run once what a test checks has happened."""


def test_runner_checks_a_body_toml_before_any_cluster_starts(tmp_path, monkeypatch):
    import hamgrav.experiments.runner as runner_module
    from hamgrav.experiments.descent import DescentExperimentConfig

    def no_cluster(*args, **kwargs):
        raise _Stop

    monkeypatch.setattr(runner_module, "dask_client", no_cluster)
    good = synthetic_toml(tmp_path / "good")
    config = DescentExperimentConfig(body=str(good))
    with pytest.raises(_Stop):  # the body passed the check: the run went on to its cluster
        runner_module.run_experiment("descent", config, workers=2)
    bad = synthetic_toml(tmp_path / "bad", units="km")
    bad.write_text(bad.read_text().replace('units = "km"', 'units = "m"'))
    with pytest.raises(BodyDataError, match=r"bad/body.toml: .*bulk density .*set units = \"km\""):
        runner_module.run_experiment("descent", config.updated({"body": str(bad)}), workers=2)


def test_swarm_experiment_loads_a_body_toml(tmp_path, monkeypatch):
    import hamgrav.experiments.swarm as swarm
    from hamgrav.experiments.runner import RunContext

    seen = {}

    def build_truth(body, *args, **kwargs):
        seen["body"] = body
        raise _Stop

    monkeypatch.setattr(swarm, "build_truth", build_truth)
    path = synthetic_toml(tmp_path, name="rock")
    with pytest.raises(_Stop):
        swarm.SwarmExperiment().run(swarm.SwarmExperimentConfig(body=str(path)), RunContext(0))
    assert seen["body"].name == "rock" and seen["body"].source["toml"] == str(path.resolve())

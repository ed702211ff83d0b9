"""The experiment runner: configs, aggregation, repetitions in-process and on a LocalCluster."""

import json

import pytest

from hamgrav.errors import HamgravError, InputError
from hamgrav.experiments.descent import DescentExperimentConfig
from hamgrav.experiments.runner import aggregate, format_range, run_experiment

TINY = DescentExperimentConfig(
    body="synthetic",
    n_mascons=60,
    orbits=2,
    arcs_per_orbit=2,
    window_spin_periods=0.5,
    min_radius_rb=1.0,
    descents=2,
    sh_degrees=(2,),
    hidden=(4,),
    adam_steps=3,
    lm_iterations=2,
)


def test_config_from_toml_and_options(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('body = "synthetic"\norbits = 3\nhidden = [8, 8]\nradius_rb = [1.3, 1.9]\n')
    config = DescentExperimentConfig.from_toml(path)
    assert config.hidden == (8, 8) and config.orbits == 3 and config.radius_rb == (1.3, 1.9)
    updated = config.updated({"hidden": "16,4", "descents": "5", "orbits": None})
    assert updated.hidden == (16, 4) and updated.descents == 5 and updated.orbits == 3
    assert DescentExperimentConfig.from_dict(updated.as_dict()) == updated


@pytest.mark.parametrize(
    "data, message",
    [
        ({"colour": 3}, "unknown key(s) ['colour']"),
        ({"orbits": "many"}, "orbits must be an integer"),
        ({"interior": "solid"}, "interior must be one of"),
        ({"radius_rb": [1.2]}, "radius_rb must be a range of two numbers"),
        ({"orbits": True}, "orbits must be an integer"),
        ({"lm_iterations": 0}, "lm_iterations must be at least 1, got 0"),
        ({"harmonic": -1e-5}, "harmonic must be >= 0"),
    ],
)
def test_bad_config_is_named(data, message):
    with pytest.raises(InputError) as info:
        DescentExperimentConfig.from_dict(data, source="my.toml")
    assert message in str(info.value) and "my.toml" in str(info.value)


@pytest.mark.parametrize("name", ["warm_iterations", "warm_patience"])
def test_continual_warm_solver_options_checked(name):
    from hamgrav.experiments.continual import ContinualExperimentConfig

    with pytest.raises(InputError, match=f"{name} must be at least 1, got 0"):
        ContinualExperimentConfig.from_dict({name: 0}, source="c.toml")


def test_aggregate_median_min_max():
    reps = [
        {"models": {"a": {"median_m": 1.0, "landed": 30, "ok": True}}},
        {"models": {"a": {"median_m": 3.0, "landed": 29, "ok": False}}},
        {"models": {"a": {"median_m": None, "landed": 28, "ok": True}}},
    ]
    agg = aggregate(reps, ("models",))["models"]["a"]
    assert agg["median_m"] == {"median": 2.0, "min": 1.0, "max": 3.0, "n": 2}
    assert agg["landed"] == {"median": 29.0, "min": 28.0, "max": 30.0, "n": 3}
    assert "ok" not in agg  # booleans are not statistics
    assert format_range(agg["median_m"]) == "2.0 (1.0-3.0)"
    assert format_range({"median": 2.0, "min": 2.0, "max": 2.0, "n": 1}) == "2.0"


def _without_timing(value):
    """``value`` without what measures the machine rather than the result: wall times and the
    peak memory of the process that ran it (in-process vs a worker process)."""
    if isinstance(value, dict):
        return {
            k: _without_timing(v)
            for k, v in value.items()
            if not (k.endswith("wall_s") or k in ("time_s", "peak_memory_mb"))
        }
    if isinstance(value, list):
        return [_without_timing(v) for v in value]
    return value


def test_local_cluster_gives_the_in_process_numbers(tmp_path, capsys):
    """Two repetitions on a 2-worker LocalCluster equal the in-process run, number for number."""
    local, _ = run_experiment("descent", TINY, seed=3, repeat=2, output=tmp_path / "a")
    cluster, _ = run_experiment(
        "descent", TINY, seed=3, repeat=2, workers=2, output=tmp_path / "b", verbose=False
    )
    assert cluster["dispatch"] == "LocalCluster of 2 workers"
    assert [r["seed"] for r in cluster["repetitions"]] == [3, 4]
    a, b = _without_timing(local["repetitions"]), _without_timing(cluster["repetitions"])
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert local["aggregate"] == cluster["aggregate"]
    # the two seeds are different draws
    assert a[0]["models"]["point-mass"]["median_m"] != a[1]["models"]["point-mass"]["median_m"]
    with capsys.disabled():
        medians = [r["models"]["sh2"]["median_m"] for r in cluster["repetitions"]]
        print(f"\nLocalCluster (2 workers) vs in-process: identical; sh2 median misses {medians}")


def test_results_folder(tmp_path):
    report, outputs = run_experiment("descent", TINY, seed=0, output=tmp_path, command="cmd")
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["command"] == "cmd" and data["config"] == TINY.as_dict()
    assert len(data["repetitions"]) == 1 and data["seeds"] == [0]
    rep = data["repetitions"][0]
    for key in ("seed", "models", "field_error", "fits", "wall_s", "n_arcs", "truth_landed"):
        assert key in rep
    assert set(data["aggregate"]) == {"models", "field_error"}
    readme = (tmp_path / "README.md").read_text()
    assert "    cmd" in readme and "| point-mass |" in readme and "## Configuration" in readme
    assert (tmp_path / "touchdown.png").stat().st_size > 1000
    assert (tmp_path / "geometry.png").stat().st_size > 1000
    assert outputs[0].artefacts["arcs"].n_arcs == rep["n_arcs"]


def test_repeat_must_be_positive():
    with pytest.raises(InputError, match="--repeat must be at least 1"):
        run_experiment("descent", TINY, repeat=0)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"workers": 2, "scheduler": "tcp://127.0.0.1:8786"}, "not both"),
        ({"scheduler": "no-port-here"}, "--scheduler no-port-here: cannot connect"),
    ],
)
def test_dask_settings_refused_before_any_work(tmp_path, settings, message):
    with pytest.raises(InputError, match=message):
        run_experiment("descent", TINY, output=tmp_path / "x", **settings)
    assert not (tmp_path / "x").exists()


def test_a_config_built_in_python_is_checked_before_any_cluster_starts(tmp_path, monkeypatch):
    import dataclasses

    import hamgrav.experiments.runner as runner_module

    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster was started for a config that cannot run")

    monkeypatch.setattr(runner_module, "dask_client", no_cluster)
    config = dataclasses.replace(TINY, hidden=(0,))  # the constructor checks nothing
    with pytest.raises(InputError, match="every value of hidden must be at least 1, got 0"):
        run_experiment("descent", config, workers=2, output=tmp_path / "x")


def test_unknown_body_refused_before_any_cluster_starts(tmp_path, monkeypatch):
    import hamgrav.experiments.runner as runner_module

    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster was started for a config that cannot run")

    monkeypatch.setattr(runner_module, "dask_client", no_cluster)
    (tmp_path / "bodies").mkdir()
    (tmp_path / "bodies" / "catalogue.json").write_text("{}")
    monkeypatch.setenv("HAMGRAV_BODIES", str(tmp_path / "bodies"))
    config = TINY.updated({"body": "vesta"})
    with pytest.raises(HamgravError, match="unknown body 'vesta'; known: synthetic"):
        run_experiment("descent", config, workers=2, output=tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_single_run_maps_its_own_work_over_the_cluster(tmp_path):
    """One repetition on a LocalCluster maps its candidate-pool informations over the
    workers (nested work units) and still gives the in-process numbers."""
    from hamgrav.experiments.solvers import SolverExperimentConfig

    config = SolverExperimentConfig(
        body="synthetic", n_mascons=60, orbits=4, arcs_per_orbit=2, window_spin_periods=0.5,
        min_radius_rb=1.0, hidden=(4,), adam_steps=3, lm_iterations=2, stages=2, picks=3,
    )  # fmt: skip
    local, _ = run_experiment("solvers", config, seed=1, verbose=False)
    cluster, _ = run_experiment("solvers", config, seed=1, workers=2, verbose=False)
    a = _without_timing(local["repetitions"][0])
    b = _without_timing(cluster["repetitions"][0])
    assert a["d_optimal"] == b["d_optimal"]
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_readme_rendered_again_from_results(tmp_path):
    from typer.testing import CliRunner

    from hamgrav.cli import app

    run_experiment("descent", TINY, seed=0, output=tmp_path, command="cmd", verbose=False)
    first = (tmp_path / "README.md").read_text()
    (tmp_path / "README.md").unlink()
    result = CliRunner().invoke(app, ["experiment", "readme", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "README.md").read_text() == first
    missing = CliRunner().invoke(app, ["experiment", "readme", str(tmp_path / "none")])
    assert missing.exit_code == 2 and "no results.json" in missing.output


def test_runs_on_other_seeds_merge_into_the_run_of_all_seeds(tmp_path):
    from typer.testing import CliRunner

    from hamgrav.cli import app

    cmd = "hamgrav experiment descent --seed {} --repeat {} -o {}"
    whole, _ = run_experiment(
        "descent", TINY, seed=3, repeat=2, output=tmp_path / "all", command=cmd.format(3, 2, "x")
    )
    for seed in (3, 4):
        run_experiment(
            "descent",
            TINY,
            seed=seed,
            output=tmp_path / f"s{seed}",
            command=cmd.format(seed, 1, "y"),
        )
    runner = CliRunner()
    folders = [str(tmp_path / "s4"), str(tmp_path / "s3")]  # any order
    result = runner.invoke(app, ["experiment", "merge", *folders, "-o", str(tmp_path / "m")])
    assert result.exit_code == 0, result.output
    merged = json.loads((tmp_path / "m" / "results.json").read_text())
    assert merged["seeds"] == [3, 4] and merged["command"] == cmd.format(3, 2, tmp_path / "m")
    a, b = _without_timing(merged["repetitions"]), _without_timing(whole["repetitions"])
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert merged["aggregate"] == whole["aggregate"]
    readme = (tmp_path / "m" / "README.md").read_text()
    assert "- seeds 3-3: `" + cmd.format(3, 1, "y") + "`" in readme
    # folders outside the working directory are named alone, in the commands too: a path of
    # this machine means nothing where the results are read
    assert [r["folder"] for r in merged["merged_from"]] == ["s4", "s3"]
    run_experiment(
        "descent", TINY, seed=5, output=tmp_path / "s5", command=cmd.format(5, 1, tmp_path / "s5")
    )
    result = runner.invoke(
        app,
        [
            "experiment",
            "merge",
            str(tmp_path / "s4"),
            str(tmp_path / "s5"),
            "-o",
            str(tmp_path / "m2"),
        ],
    )
    assert result.exit_code == 0, result.output
    part = json.loads((tmp_path / "m2" / "results.json").read_text())["merged_from"][1]
    assert part["command"] == cmd.format(5, 1, "s5") and str(tmp_path) not in str(part)
    assert (tmp_path / "m" / "touchdown.png").read_bytes() == (
        tmp_path / "s3" / "touchdown.png"
    ).read_bytes()
    # re-rendered from its results.json alone, the same README
    result = runner.invoke(app, ["experiment", "readme", str(tmp_path / "m")])
    assert result.exit_code == 0 and (tmp_path / "m" / "README.md").read_text() == readme
    # runs that do not make one run are refused in one line, nothing written
    for bad, says in (
        ([str(tmp_path / "s3"), str(tmp_path / "all")], "share seeds"),
        ([str(tmp_path / "s3")], "two or more"),
        ([str(tmp_path / "s3"), str(tmp_path / "bad")], "is one of the folders merged"),
    ):
        result = runner.invoke(app, ["experiment", "merge", *bad, "-o", str(tmp_path / "bad")])
        assert result.exit_code == 2 and says in result.output, result.output
        assert not (tmp_path / "bad").exists()
    other = TINY.updated({"hidden": [5]})
    run_experiment("descent", other, seed=5, output=tmp_path / "s5", command="c")
    result = runner.invoke(
        app, ["experiment", "merge", str(tmp_path / "s4"), str(tmp_path / "s5"), "-o", "bad"]
    )
    assert result.exit_code == 2 and "another config" in result.output


def _numbers(value, path=""):
    """Every number in ``value`` by its path (booleans and strings as they are)."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            out.update(_numbers(v, f"{path}/{k}"))
        return out
    if isinstance(value, list):
        out = {}
        for i, v in enumerate(value):
            out.update(_numbers(v, f"{path}/{i}"))
        return out
    return {path: value}


#: How a fit stopped: at its minimum, sums that differ in the last bits may end it by one
#: rule or the other (relative change 2e-16 < 1e-6 at iteration 16, or the damping saturated
#: at 21, with the same cost to 1e-16); the costs and everything computed from them are
#: compared.
STOPPING_RECORD = {"outcome", "message", "iterations", "best_iteration"}


def test_fits_distributed_over_the_cluster_give_the_in_process_numbers(tmp_path):
    """One repetition whose every fit sends its arcs to a 2-worker LocalCluster
    (DistributedArcProblem): the numbers of the in-process run, to rounding (the sums over
    arcs are added chunk by chunk, not 64 arcs at a time)."""
    local, _ = run_experiment("descent", TINY, seed=3, output=tmp_path / "a", verbose=False)
    spread, _ = run_experiment(
        "descent",
        TINY,
        seed=3,
        workers=2,
        distribute_fits=True,
        output=tmp_path / "b",
        verbose=False,
    )
    assert spread["dispatch"] == "LocalCluster of 2 workers, each fit's arcs on the workers"
    a = _numbers(_without_timing(local["repetitions"]))
    b = _numbers(_without_timing(spread["repetitions"]))
    assert a.keys() == b.keys()
    for key, value in a.items():
        if key.rsplit("/", 1)[-1] in STOPPING_RECORD:
            continue
        if isinstance(value, float):
            assert b[key] == pytest.approx(value, rel=1e-6, abs=1e-9), key
        else:
            assert b[key] == value, key
    # and the sums were formed on the workers: added chunk by chunk, their last bits differ
    assert any(a[k] != b[k] for k in a if isinstance(a[k], float))


def test_distributed_fits_need_a_cluster():
    with pytest.raises(InputError, match="--distribute-fits .* give --workers N"):
        run_experiment("descent", TINY, distribute_fits=True)

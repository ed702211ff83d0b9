"""Every job is sized before it starts: options each within its bound whose product does not
fit in memory are refused in one line (status 2) with the figure and the fix, and seeds must
fit the 64-bit integers they are stored in."""

import pytest
from typer.testing import CliRunner

from hamgrav.cli import app
from hamgrav.errors import InputError
from hamgrav.io.arcs import save_arcs
from hamgrav.sizing import fit_bytes, network_parameters, parse_memory

runner = CliRunner()


def _error(result, *needles):
    """The run failed as a user error: status 2, one 'error:' line holding every needle."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    text = " ".join(result.output.split())
    assert text.startswith("error:") and "error:" not in text[6:], result.output
    for needle in needles:
        assert needle in text, (needle, text)
    return text, lines


@pytest.fixture(scope="module")
def files(tmp_path_factory, small_arcs):
    folder = tmp_path_factory.mktemp("sizes")
    arcs = save_arcs(small_arcs, folder / "arcs.h5")
    model = folder / "sh2.h5"
    result = runner.invoke(app, ["fit", str(arcs), "--model", "sh:2", "-o", str(model)])
    assert result.exit_code == 0, result.output
    return arcs, model


BIG = 'body = "synthetic"\n[orbits]\ncount = 1000\n[tracking]\narcs_per_orbit = 10000\n'
BIG += "samples_per_arc = 10000\n"


def test_sizes_parse_and_add_up():
    assert parse_memory("8GiB") == 8 * 2**30 and parse_memory("16GB") == 16 * 10**9
    assert parse_memory("1.5 TiB") == int(1.5 * 2**40) and parse_memory("4096") == 4096
    for bad in ("8 bananas", "-1GiB", "", "0"):
        with pytest.raises(InputError, match="--max-memory must be a"):
            parse_memory(bad)
    # three hidden layers of 1024: 2.1 million parameters, a 32 TiB normal matrix
    n = network_parameters((1024, 1024, 1024))
    assert n == 3 * 1024 + 2 * 1024**2 + 1024 + 3 * 1024 + 1
    matrix = n * n * 8
    assert 32 * 2**40 < matrix < 33 * 2**40
    parts = fit_bytes(100, 40, n)
    assert parts[f"the normal matrices ({n} x {n})"] == 3 * matrix


def test_a_campaign_too_big_for_memory_is_refused_before_simulating(tmp_path):
    toml = tmp_path / "big.toml"
    toml.write_text(BIG)
    out = tmp_path / "a.h5"
    result = runner.invoke(app, ["simulate", str(toml), "-o", str(out)])
    text, _ = _error(
        result,
        "big.toml needs about 18.9 TiB of memory",
        "the arcs (1000 orbits x 10000 arcs x 10000 samples)",
        "lower [orbits] count, [tracking] arcs_per_orbit or samples_per_arc",
        "or pass --max-memory SIZE",
    )
    assert "of memory available" in text and "simulating" not in result.output.split("error")[0]
    assert not out.exists()
    # a small campaign against a stated limit
    small = tmp_path / "small.toml"
    small.write_text('body = "synthetic"\n[orbits]\ncount = 2\n')
    result = runner.invoke(app, ["simulate", str(small), "-o", str(out), "--max-memory", "1KiB"])
    _error(result, "more than --max-memory 1KiB;")
    result = runner.invoke(app, ["simulate", str(small), "-o", str(out), "--max-memory", "lots"])
    _error(result, "--max-memory must be a size such as 8GiB, 512MiB or 16GB, got 'lots'")


def test_a_pool_too_big_for_memory_is_refused(files, tmp_path):
    pool = tmp_path / "pool.toml"
    pool.write_text(BIG)
    result = runner.invoke(app, ["select", str(files[1]), "--pool", str(pool)])
    _error(
        result,
        "choosing from the pool",
        "the predicted arcs (1000 candidates x 10000 arcs x 10000 samples)",
        "lower [orbits] count, [tracking] arcs_per_orbit or samples_per_arc of the pool",
    )


def test_layers_each_within_bound_but_too_big_together_are_refused(files, tmp_path):
    out = tmp_path / "m.h5"
    result = runner.invoke(
        app, ["fit", str(files[0]), "--hidden", "1024,1024,1024", "-o", str(out)]
    )
    _error(
        result,
        "fitting 2104321 parameters to 9 arcs needs about 96.7 TiB of memory",
        "the normal matrices (2104321 x 2104321)",
        "use fewer or smaller --hidden layers",
    )
    result = runner.invoke(
        app, ["fit", str(files[0]), "--model", "sh:40", "--max-memory", "1MiB", "-o", str(out)]
    )
    _error(result, "fitting 1677 parameters", "more than --max-memory 1MiB", "lower the degree")
    assert not out.exists()


def test_seeds_must_fit_their_integers(files, tmp_path):
    toml = tmp_path / "seed.toml"
    toml.write_text(f'body = "synthetic"\nseed = {2**70}\n[orbits]\ncount = 2\n')
    out = tmp_path / "a.h5"
    _error(
        runner.invoke(app, ["simulate", str(toml), "-o", str(out)]),
        f"seed.toml: seed must be an integer in [0, 2**63 - 1] (seeds are stored as 64-bit "
        f"integers), got {2**70}",
    )
    assert not out.exists()
    _error(
        runner.invoke(app, ["fit", str(files[0]), "--seed", str(2**70), "-o", str(out)]),
        "--seed must be an integer in [0, 2**63 - 1]",
    )
    _error(
        runner.invoke(app, ["select", str(files[1]), "--pool", str(toml), "--seed", str(2**64)]),
        "--seed must be an integer in [0, 2**63 - 1]",
    )
    # the last seed of the repetitions counts
    result = runner.invoke(
        app,
        ["experiment", "descent", "--seed", str(2**63 - 1), "--repeat", "2", "-o", str(tmp_path)],
    )
    _error(result, "with --repeat 2 (seeds up to --seed + 1)", "give a smaller seed")


@pytest.mark.parametrize("count", ["1e9", "1000000000", "5.5", "9"])
def test_body_mascons_beyond_the_volume_samples_are_refused(count):
    result = runner.invoke(app, ["body", "synthetic", "--mascons", count])
    _error(result, "--mascons must be one integer in [10, 100000]", f"got '{count}'")


def test_body_mascons_in_exponent_notation_are_read():
    result = runner.invoke(app, ["body", "synthetic", "--json", "--mascons", "2e2"])
    assert result.exit_code == 0, result.output
    assert '"truth_mascons": 200' in result.output


def test_experiments_too_big_for_memory_are_refused_before_they_run(tmp_path):
    # every option within its bound, their product not: 1000 orbits x 10 000 arcs
    out = tmp_path / "out"
    result = runner.invoke(
        app,
        [
            "experiment",
            "descent",
            "--body",
            "synthetic",
            "--orbits",
            "1000",
            "--arcs-per-orbit",
            "10000",
            "-o",
            str(out),
            "--max-memory",
            "16GiB",
        ],
    )
    _error(
        result,
        "experiment descent needs about 77.7 GiB of memory",
        "(of which the arcs (1000 orbits x 10000 arcs x 40 samples)",
        "more than --max-memory 16GiB; lower --orbits, --arcs-per-orbit, --hidden or the SH "
        "degrees, or pass --max-memory SIZE",
    )
    # by default, against the memory this machine has
    huge = ["--hidden", "1024,1024,1024"]
    result = runner.invoke(app, ["experiment", "swarm", "--body", "synthetic", *huge])
    text, _ = _error(result, "experiment swarm needs about", "TiB of memory")
    assert "of memory available" in text and not out.exists()
    # repetitions at once on a LocalCluster multiply; the figure and the fix say so
    # (two layers of 128: 17 153 weights and 28 A/m, a 2.2 GiB normal matrix three times)
    one = ["experiment", "swarm", "--body", "synthetic", "--hidden", "128,128", "-o", str(out)]
    result = runner.invoke(app, [*one, "--max-memory", "8GiB"])
    _error(result, "experiment swarm needs about 10.7 GiB", "more than --max-memory 8GiB;")
    result = runner.invoke(app, [*one, "--repeat", "4", "--workers", "2", "--max-memory", "16GiB"])
    _error(
        result,
        "experiment swarm (2 repetitions at once) needs about 21.3 GiB",
        "lower --arcs, --samples-per-arc, --hidden or the SH degrees, or run fewer --workers",
    )
    assert not out.exists()


def test_experiment_sizes_count_the_largest_fit_of_each_experiment():
    from hamgrav.experiments.runner import check_job_memory, experiment_names, get_experiment
    from hamgrav.sizing import fit_bytes

    for name in experiment_names():
        experiment = get_experiment(name)
        config = experiment.default_config()
        parts = config.memory_parts()
        # every experiment is sized, and its default run fits in a laptop's memory
        assert parts and 0 < sum(parts.values()) < 2**30, name
        check_job_memory(experiment, config, repeat=8, workers=2, max_memory="2GiB")
    # the largest of the selection experiment's fits: SH 12 (165 coefficients) against a
    # [24, 24] network (721 parameters), on its 16 x 7 arcs of 40 samples
    parts = get_experiment("selection").default_config().memory_parts()
    expected = fit_bytes(112, 40, 721)
    for what in ("the variational integrator", "the normal matrices (721 x 721)"):
        assert parts[what] == expected[what]

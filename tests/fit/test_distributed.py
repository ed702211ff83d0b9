"""One fit's sums over arcs on a Dask cluster (hamgrav.fit.distributed): the same numbers as
in-process, chunks held by the workers, a lost worker's chunk computed again elsewhere."""

import os
import signal
import time

import numpy as np
import pytest

from hamgrav.core.problem import ArcProblem
from hamgrav.experiments.runner import dask_client
from hamgrav.fit.distributed import DistributedArcProblem
from hamgrav.fit.estimator import GravityEstimator


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=2) as client:
        yield client


def _network(body, **kw):
    return GravityEstimator(
        "network", hidden=(6,), solver="lm", lm_max_iter=4, body=body, seed=3, **kw
    )


def _network_fit(body, **kw):
    # every arc trains (nothing held out): the fit's every step shows in its cost
    return _network(body, validation_fraction=0.0, **kw)


def test_sums_over_chunks_equal_the_in_process_sums(client, small_arcs, synthetic_truth):
    est = _network(synthetic_truth.body)
    model, _ = est.build_model(small_arcs)
    theta = est.initial_params(model, small_arcs)
    theta = theta + 1e-2 * np.random.default_rng(0).standard_normal(theta.shape)
    local = ArcProblem(model, small_arcs)
    remote = DistributedArcProblem(model, small_arcs, client=client, chunks=3)
    assert remote.n_chunks == 3 and list(remote.bounds) == [0, 3, 6, 9]
    # a selection across chunk borders, out of order, as a fit's training arcs are given
    picked = np.array([7, 1, 2, 3, 8, 5, 0])
    c0, g0, h0 = local.normal_equations(theta, picked)
    c1, g1, h1 = remote.normal_equations(theta, picked)
    assert c1 == pytest.approx(c0, rel=1e-12)
    np.testing.assert_allclose(g1, g0, rtol=1e-10, atol=1e-12 * np.abs(g0).max())
    np.testing.assert_allclose(h1, h0, rtol=1e-10, atol=1e-12 * np.abs(h0).max())
    np.testing.assert_allclose(remote.arc_costs(theta, picked), local.arc_costs(theta, picked))
    assert remote.cost(theta) == pytest.approx(local.cost(theta), rel=1e-12)
    c2, g2 = remote.gradient(theta, picked)
    assert c2 == pytest.approx(c0, rel=1e-12)
    np.testing.assert_allclose(g2, g0, rtol=1e-10, atol=1e-12 * np.abs(g0).max())
    # the workers' problems take the client's gradient method
    forward = DistributedArcProblem(
        model, small_arcs, client=client, chunks=3, gradient_method="forward"
    )
    np.testing.assert_allclose(forward.gradient(theta)[1], local.gradient(theta)[1], rtol=1e-9)

    def methods():
        from hamgrav.fit.distributed import _PROBLEMS

        return {token: p.gradient_method for token, p in _PROBLEMS.items()}

    seen = {}
    for found in client.run(methods).values():
        seen.update(found)
    mine = {
        token: method
        for token, method in seen.items()
        if token.split("-")[0] in {c.result()["token"].split("-")[0] for c in forward._chunks}
    }
    assert set(mine.values()) == {"forward"} and len(mine) == 3


def test_weighted_sums_over_chunks_equal_the_in_process_sums(client, small_arcs, synthetic_truth):
    """Each chunk carries its arcs' weights: the sums equal the in-process weighted sums."""
    est = _network(synthetic_truth.body)
    model, _ = est.build_model(small_arcs)
    theta = est.initial_params(model, small_arcs)
    weights = np.linspace(0.2, 5.0, small_arcs.n_arcs)
    local = ArcProblem(model, small_arcs, arc_weights=weights)
    remote = DistributedArcProblem(model, small_arcs, client=client, chunks=3, arc_weights=weights)
    picked = np.array([7, 1, 2, 3, 8, 5, 0])
    c0, g0, h0 = local.normal_equations(theta, picked)
    c1, g1, h1 = remote.normal_equations(theta, picked)
    assert c1 == pytest.approx(c0, rel=1e-12)
    assert c0 != pytest.approx(ArcProblem(model, small_arcs).cost(theta, picked), rel=1e-3)
    np.testing.assert_allclose(g1, g0, rtol=1e-10, atol=1e-12 * np.abs(g0).max())
    np.testing.assert_allclose(h1, h0, rtol=1e-10, atol=1e-12 * np.abs(h0).max())
    np.testing.assert_allclose(remote.gradient(theta, picked)[1], g0, rtol=1e-9, atol=1e-12)


@pytest.mark.filterwarnings("ignore:the fit looks overfit")
@pytest.mark.parametrize("term", ["network", "sh"])
def test_a_distributed_fit_equals_the_in_process_fit(client, small_arcs, synthetic_truth, term):
    body = synthetic_truth.body
    if term == "network":
        here, there = _network_fit(body), _network_fit(body, client=client)
    else:
        here = GravityEstimator("sh", degree=3, kaula=1e-6, body=body)
        there = GravityEstimator("sh", degree=3, kaula=1e-6, body=body, client=client)
    here.fit(small_arcs)
    there.fit(small_arcs)
    assert there.result_.iterations == here.result_.iterations > 1
    np.testing.assert_allclose(there.result_.history["cost"], here.result_.history["cost"], 1e-10)
    assert there.result_.cost == pytest.approx(here.result_.cost, rel=1e-10)
    scale = np.abs(here.params_).max()
    np.testing.assert_allclose(there.params_, here.params_, rtol=1e-10, atol=1e-10 * scale)
    assert there.result_.cost < there.result_.initial_cost  # it took steps


def test_a_lost_worker_chunk_is_computed_again(small_arcs, synthetic_truth):
    est = _network(synthetic_truth.body)
    model, _ = est.build_model(small_arcs)
    theta = est.initial_params(model, small_arcs)
    expected = ArcProblem(model, small_arcs).normal_equations(theta)
    with dask_client(workers=2) as client:
        remote = DistributedArcProblem(model, small_arcs, client=client, chunks=4)
        first = remote.normal_equations(theta)
        held = client.who_has(remote._chunks)
        worker = next(iter(next(iter(held.values()))))
        # killed with no goodbye: its chunks' data and problems are gone with it
        pid = client.run(os.getpid, workers=[worker])[worker]
        os.kill(pid, signal.SIGKILL)
        deadline = time.monotonic() + 60
        while worker in client.scheduler_info()["workers"]:
            assert time.monotonic() < deadline, "the worker did not go"
            time.sleep(0.1)
        again = remote.normal_equations(theta)
    for got in (first, again):
        assert got[0] == pytest.approx(expected[0], rel=1e-12)
        np.testing.assert_allclose(got[2], expected[2], rtol=1e-10, atol=1e-12)


def test_fit_command_on_a_local_cluster(tmp_path, small_arcs):
    from typer.testing import CliRunner

    from hamgrav.cli import app
    from hamgrav.io.arcs import save_arcs
    from hamgrav.io.models import load_model

    runner = CliRunner()
    arcs = save_arcs(small_arcs, tmp_path / "arcs.h5")
    models = {}
    for name, extra in (("here", []), ("there", ["--workers", "2"])):
        out = tmp_path / f"{name}.h5"
        args = ["fit", str(arcs), "--model", "sh:3", "--kaula", "1e-6", "-o", str(out), *extra]
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        models[name] = load_model(out)
    here, there = models["here"], models["there"]
    np.testing.assert_allclose(there.params, here.params, rtol=1e-10, atol=1e-12)
    assert there.solver["cost"] == pytest.approx(here.solver["cost"], rel=1e-10)
    for bad, says in (
        (["--workers", "-1"], "--workers"),
        (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not both"),
        (["--scheduler", "tcp://127.0.0.1:1"], "--scheduler tcp://127.0.0.1:1: cannot connect"),
    ):
        out = tmp_path / "bad.h5"
        result = runner.invoke(app, ["fit", str(arcs), "--model", "sh:2", "-o", str(out), *bad])
        assert result.exit_code == 2 and says in result.output, result.output
        assert not out.exists()


def test_a_cluster_left_without_workers_stops_the_call(small_arcs, synthetic_truth, monkeypatch):
    from hamgrav.errors import DistributedError
    from hamgrav.fit import distributed

    monkeypatch.setattr(distributed, "_POLL_S", 0.5)
    monkeypatch.setattr(distributed, "NO_WORKERS_S", 1.0)
    est = _network(synthetic_truth.body)
    model, _ = est.build_model(small_arcs)
    theta = est.initial_params(model, small_arcs)
    with dask_client(workers=1) as client:
        remote = DistributedArcProblem(model, small_arcs, client=client, chunks=2)
        remote.cost(theta)
        client.cluster.scale(0)
        deadline = time.monotonic() + 60
        while client.nthreads():
            assert time.monotonic() < deadline, "the worker did not go"
            time.sleep(0.1)
        with pytest.raises(DistributedError, match="no worker for"):
            remote.cost(theta)

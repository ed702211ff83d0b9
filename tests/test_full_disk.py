"""simulate, fit, export and experiment on a disk that refuses their writes: one line naming
the file and the disk's error (status 2), and nothing left behind (no .part, no half results
folder, no checkpoint of a fit that never got one).

Two ways to fill a disk, each where the system allows it:

- ``fsize``: the command runs with a file-size limit (``RLIMIT_FSIZE``, SIGXFSZ ignored, as
  Python starts): a write beyond it fails with EFBIG. Any POSIX system; the limit applies to
  every file the process writes (heyoka's compile cache too, which says so in its own log
  lines).
- ``tmpfs``: the output folder is a small tmpfs mounted in a mount namespace of the command
  alone (``unshare --mount``, as root or with an unprivileged user namespace): a real ENOSPC.
  Skipped, with the reason, where neither is allowed.
"""

import functools
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hamgrav.cli import app
from hamgrav.io.models import checkpoint_path_for, load_model

runner = CliRunner()

CAMPAIGN = """
body = "synthetic"
interior = "uniform"
n_mascons = 60
seed = 5
[orbits]
families = [[1.5, 30.0], [1.9, 70.0]]
[tracking]
arcs_per_orbit = 2
window_spin_periods = 0.3
"""
#: The Adam fit of these tests: a checkpoint at steps 25, 50, 75 and 100 (each about 10 kB,
#: the model file about 230 kB: mostly the body's mesh).
FIT = ["--model", "network", "--hidden", "4", "--steps", "100"]
TINY_DESCENT = [
    "experiment", "descent", "--body", "synthetic", "--n-mascons", "60", "--orbits", "2",
    "--arcs-per-orbit", "2", "--window-spin-periods", "0.5", "--min-radius-rb", "1.0",
    "--descents", "3", "--sh-degrees", "2", "--hidden", "4", "--adam-steps", "3",
    "--lm-iterations", "6",
]  # fmt: skip


@functools.cache
def _unshare() -> list[str] | None:
    """The command prefix that runs a command in its own mount namespace, or None."""
    if shutil.which("unshare") is None or not sys.platform.startswith("linux"):
        return None
    probe = Path(os.environ.get("TMPDIR", "/tmp"))
    for prefix in (["unshare", "--mount"], ["unshare", "--mount", "--map-root-user"]):
        script = f"mount -t tmpfs -o size=16k tmpfs {probe}"
        done = subprocess.run([*prefix, "sh", "-c", script], capture_output=True, timeout=30)
        if done.returncode == 0:
            return prefix
    return None


def _why_not(kind: str) -> str | None:
    if kind == "fsize":
        try:
            import resource  # noqa: F401
        except ImportError:
            return "no resource module (not a POSIX system): no file-size limit"
        return None
    if _unshare() is None:
        return "cannot mount a tmpfs in a mount namespace here (no unshare, or it may not mount)"
    return None


@pytest.fixture(params=["fsize", "tmpfs"])
def full_disk(request, tmp_path):
    """``run(args, folder, size)``: ``hamgrav args`` in a subprocess that can write at most
    ``size`` bytes to a file (fsize) or to ``folder`` (tmpfs); returns (exit status,
    stderr, the names in ``folder`` when the command ended)."""
    reason = _why_not(request.param)
    if reason:
        pytest.skip(reason)
    command = [sys.executable, "-m", "hamgrav.cli"]

    def run(args, folder: Path, size: int):
        folder.mkdir(exist_ok=True)
        args = [str(a) for a in args]
        if request.param == "fsize":

            def limit():
                import resource

                signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
                resource.setrlimit(resource.RLIMIT_FSIZE, (size, resource.RLIM_INFINITY))

            done = subprocess.run(
                [*command, *args], capture_output=True, text=True, preexec_fn=limit, timeout=300
            )
            return done.returncode, done.stderr, sorted(p.name for p in folder.iterdir())
        # the tmpfs is the folder's only in the namespace: list it there, before it goes
        listing = tmp_path / "listing.txt"
        script = (
            'mount -t tmpfs -o size="$1" tmpfs "$2" || exit 99; shift 3; "$@"; status=$?; '
            'ls -A "$0" > "$LISTING"; exit $status'
        )
        done = subprocess.run(
            [*_unshare(), "sh", "-c", script, folder, f"{size}", folder, "--", *command, *args],
            capture_output=True,
            text=True,
            env={**os.environ, "LISTING": str(listing)},
            timeout=300,
        )
        assert done.returncode != 99, done.stderr
        return done.returncode, done.stderr, sorted(listing.read_text().split())

    run.errno = {"fsize": "(EFBIG)", "tmpfs": "(ENOSPC)"}[request.param]
    run.kind = request.param
    return run


def _one_line(stderr: str, path: Path, errno_name: str) -> str:
    """The error line, checked: the only line of hamgrav's but its progress bars (heyoka's
    own log lines aside), naming the file and the disk's error."""
    lines = [
        line
        for line in stderr.splitlines()
        if line.strip() and "━" not in line and "[heyoka-" not in line
    ]
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"error: cannot write {path}: "), stderr
    assert errno_name in lines[0] and ".part" not in lines[0], stderr
    return lines[0]


@pytest.fixture(scope="module")
def arcs_file(tmp_path_factory, small_arcs):
    from hamgrav.io.arcs import save_arcs

    return save_arcs(small_arcs, tmp_path_factory.mktemp("full-disk") / "arcs.h5")


@pytest.fixture(scope="module")
def network_model(arcs_file):
    out = arcs_file.with_name("network.h5")
    fit = ["fit", str(arcs_file), *FIT[:-1], "30", "-o", str(out)]
    assert runner.invoke(app, fit).exit_code == 0
    return out


def test_simulate(full_disk, tmp_path):
    campaign = tmp_path / "c.toml"
    campaign.write_text(CAMPAIGN)
    out = tmp_path / "disk"
    args = ["simulate", campaign, "-o", out / "arcs.h5", "--oem", out / "oem"]
    status, stderr, left = full_disk([*args, "--spk", out / "s.bsp"], out, 16_384)
    assert status == 2
    _one_line(stderr, out / "arcs.h5", full_disk.errno)
    assert left == []


def test_fit_before_its_first_checkpoint_leaves_nothing(full_disk, tmp_path, arcs_file):
    out = tmp_path / "disk"
    status, stderr, left = full_disk(["fit", arcs_file, *FIT, "-o", out / "m.h5"], out, 4096)
    assert status == 2
    line = _one_line(stderr, checkpoint_path_for(out / "m.h5"), full_disk.errno)
    assert line.endswith("the fit had no checkpoint yet: nothing was saved, run the command again")
    assert left == []  # nothing blocks a plain rerun


def test_fit_whose_model_cannot_be_written_keeps_its_last_checkpoint(
    full_disk, tmp_path, arcs_file
):
    out = tmp_path / "disk"
    model = out / "m.h5"
    ckpt = checkpoint_path_for(model)
    fit = ["fit", arcs_file, *FIT, "-o", model]
    status, stderr, left = full_disk(fit, out, 65_536)
    assert status == 2
    line = _one_line(stderr, model, full_disk.errno)
    assert line.endswith(
        f"the last checkpoint is kept (Adam step 100): continue with the same command and "
        f"--resume ({ckpt})"
    )
    assert left == [ckpt.name]
    if full_disk.kind == "fsize":  # (a tmpfs goes with its namespace) room again: resume
        result = runner.invoke(app, [str(a) for a in fit] + ["--resume"])
        assert result.exit_code == 0, result.output
        assert sorted(p.name for p in out.iterdir()) == ["m.h5"]
        full = tmp_path / "full.h5"
        assert runner.invoke(app, [str(a) for a in fit[:-1]] + [str(full)]).exit_code == 0
        assert np.array_equal(load_model(model).params, load_model(full).params)


def test_export(full_disk, tmp_path, network_model):
    out = tmp_path / "disk"
    args = ["export", network_model, "--format", "icgem", "--degree", "20", "-o", out / "m.gfc"]
    status, stderr, left = full_disk(args, out, 4096)
    assert status == 2
    _one_line(stderr, out / "m.gfc", full_disk.errno)
    assert left == []


def test_experiment(full_disk, tmp_path):
    """results.json fits, the first figure does not: neither is left, nor the folder."""
    out = tmp_path / "disk"
    status, stderr, left = full_disk([*TINY_DESCENT, "-o", out / "run"], out, 65_536)
    assert status == 2
    # after the runner's progress lines
    after_the_run = stderr.split("repetition 1/1 done", 1)[-1].split("\n", 1)[-1]
    _one_line(after_the_run, out / "run" / "geometry.png", full_disk.errno)
    assert left == []

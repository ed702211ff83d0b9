"""Fits killed at random times, as a batch scheduler (SIGTERM) or Ctrl-C (SIGINT) kills them,
then continued as their message says: every run ends with a model equal to an uninterrupted
fit's, and no file is left behind but the model.

The fits run in children forked from one process that has imported hamgrav (see
``fork_server.py``): 50 kills then cost about a minute of CPU, not the libraries' start twice
per kill.
"""

import json
import os
import signal
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hamgrav.cli import Terminated, app
from hamgrav.io.models import checkpoint_path_for, load_model

runner = CliRunner()

#: Kills per solver (alternately SIGTERM and SIGINT): 50 in all.
KILLS = 25
#: The fits killed: a tiny network, by Adam (a checkpoint every 25 steps) and by LM (one
#: each accepted iteration). Each runs for a few tenths of a second.
FITS = {
    "adam": ["--model", "network", "--hidden", "4", "--steps", "300"],
    "lm": ["--model", "network", "--hidden", "4", "--solver", "lm"],
}


class ForkServer:
    """``tests/fork_server.py`` in a subprocess: ``run`` one command, signalled or not."""

    def __init__(self):
        script = Path(__file__).with_name("fork_server.py")
        self.proc = subprocess.Popen(
            [sys.executable, str(script)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )

    def run(
        self, args, log: Path, kill_after=None, signum=signal.SIGTERM, after_file=None
    ) -> tuple[int, float]:
        """(exit status, -signal if the signal ended it; seconds it ran) of ``hamgrav args``,
        sent ``signum`` after ``kill_after`` seconds (counted from the moment ``after_file``
        appears, if given) unless it ended before."""
        request = {
            "args": [str(a) for a in args],
            "log": str(log),
            "kill_after": kill_after,
            "after_file": None if after_file is None else str(after_file),
        }
        self.proc.stdin.write(json.dumps({**request, "signal": int(signum)}) + "\n")
        self.proc.stdin.flush()
        answer = self.proc.stdout.readline()
        assert answer, "the fork server died"
        answer = json.loads(answer)
        return answer["status"], answer["seconds"]

    def close(self):
        self.proc.stdin.close()
        self.proc.wait(timeout=30)


@pytest.fixture(scope="module")
def server():
    s = ForkServer()
    yield s
    s.close()


@pytest.fixture(scope="module")
def arcs_file(tmp_path_factory, small_arcs):
    from hamgrav.io.arcs import save_arcs

    return save_arcs(small_arcs, tmp_path_factory.mktemp("kill-arcs") / "arcs.h5")


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())  # hidden .part files too


@pytest.mark.parametrize("solver", sorted(FITS))
def test_fits_killed_at_random_times_end_as_if_never_killed(solver, server, arcs_file, tmp_path):
    fit = ["fit", arcs_file, *FITS[solver]]
    logs = tmp_path / "logs"
    logs.mkdir()
    reference = tmp_path / "reference.h5"
    status, seconds = server.run([*fit, "-o", reference], logs / "reference.txt")
    assert status == 0, (logs / "reference.txt").read_text()
    expected = load_model(reference).params
    rng = np.random.default_rng(41 + sorted(FITS).index(solver))
    outcomes = Counter()
    for k in range(KILLS):
        folder = tmp_path / f"run-{k}"
        folder.mkdir()
        out = folder / "m.h5"
        ckpt = checkpoint_path_for(out)
        signum = (signal.SIGTERM, signal.SIGINT)[k % 2]
        log = logs / f"{k}.txt"
        if k % 3 == 2:
            # a kill timed from the first checkpoint: however fast or loaded the machine, a
            # share of the kills tests resuming (random times alone left 4 of 25 there once)
            when = dict(kill_after=rng.uniform(0, seconds / 10), after_file=ckpt)
        else:
            when = dict(kill_after=rng.uniform(0, seconds))
        status, _ = server.run([*fit, "-o", out], log, signum=signum, **when)
        text = log.read_text()
        said = text.strip().splitlines()[-1] if text.strip() else ""
        how = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted"
        context = f"run {k} ({signum.name}, status {status}): {text[-600:]}"
        assert "Traceback" not in text and "internal error" not in text, context
        again = None
        if status == 0:
            outcomes["ended before the signal"] += 1
            assert _names(folder) == ["m.h5"], context
        elif ckpt.exists():
            outcomes["checkpoint kept"] += 1
            assert status == 128 + signum and said.startswith(how), context
            assert _names(folder) == [ckpt.name], context
            assert "the last checkpoint is kept" in said and "--resume" in said, context
            again = [*fit, "-o", out, "--resume"]
        elif out.exists():  # as the model was written, or once the command had returned
            outcomes["model complete as the signal came"] += 1
            assert _names(folder) == ["m.h5"], context
        else:
            outcomes["stopped before the first checkpoint"] += 1
            assert _names(folder) == [], context
            again = [*fit, "-o", out]
        if status != 0 and said.startswith(how):  # the command's own handlers
            assert status == 128 + signum, context
        elif status != 0:  # typer's (a silent 130) or the default action, outside the command
            outcomes["signalled outside the command"] += 1
            # before the command ran it said nothing; after it had returned (a loaded machine
            # can deliver the signal that late) its own report is the last line, and the
            # model is complete
            assert status in (128 + signum, -signum), context
            assert not said or (out.exists() and not ckpt.exists()), context
        if again is not None:
            status, _ = server.run(again, log)
            assert status == 0, f"run {k} again: {log.read_text()[-600:]}"
        assert _names(folder) == ["m.h5"], context
        assert np.array_equal(load_model(out).params, expected), context
    print(f"\n{solver}: {KILLS} kills within {seconds:.2f} s: {dict(outcomes)}")
    assert outcomes["checkpoint kept"] >= KILLS // 5, outcomes  # the test tested resuming


def test_sigterm_keeps_the_last_checkpoint_and_says_which(arcs_file, tmp_path, monkeypatch):
    """SIGTERM (here: raised where the handler would raise it, after the second checkpoint)
    exits with status 143 naming what was kept; --resume ends where an uninterrupted fit
    ends."""
    from hamgrav.io import models

    fit = ["fit", str(arcs_file), *FITS["adam"][:-1], "60"]
    full = tmp_path / "full.h5"
    assert runner.invoke(app, [*fit, "-o", str(full)]).exit_code == 0
    real_save, saved = models.save_checkpoint, []

    def save_then_terminate(*args):
        real_save(*args)
        saved.append(args[2]["step"])
        if len(saved) == 2:
            raise Terminated

    monkeypatch.setattr(models, "save_checkpoint", save_then_terminate)
    out = tmp_path / "m.h5"
    result = runner.invoke(app, [*fit, "-o", str(out)])
    assert result.exit_code == 143
    ckpt = checkpoint_path_for(out)
    assert result.output.strip().splitlines()[-1] == (
        "terminated (SIGTERM); the last checkpoint is kept (Adam step 50): continue with the "
        f"same command and --resume ({ckpt})"
    )
    assert _names(tmp_path) == ["full.h5", ckpt.name]
    monkeypatch.setattr(models, "save_checkpoint", real_save)
    assert runner.invoke(app, [*fit, "-o", str(out), "--resume"]).exit_code == 0
    assert _names(tmp_path) == ["full.h5", "m.h5"]
    assert np.array_equal(load_model(out).params, load_model(full).params)


@pytest.fixture
def sigint_handled():
    """Python's own SIGINT handler, as in a terminal (a shell's background job ignores it)."""
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, outer)


def test_a_signal_as_the_model_is_written_says_the_fit_is_complete(
    arcs_file, tmp_path, monkeypatch, sigint_handled
):
    """A signal that arrives while the model file is moved into place (held until it is)
    leaves the model, not its stale checkpoint, and says so."""
    from hamgrav import files

    real_replace = os.replace

    def replace_then_signal(src, dst):
        real_replace(src, dst)
        if str(dst).endswith("m.h5"):
            signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(files.os, "replace", replace_then_signal)
    out = tmp_path / "m.h5"
    result = runner.invoke(app, ["fit", str(arcs_file), *FITS["adam"][:-1], "30", "-o", str(out)])
    assert result.exit_code == 130
    assert result.output.strip().splitlines()[-1] == (
        f"interrupted; the fit is complete and its model written: {out}"
    )
    assert _names(tmp_path) == ["m.h5"]
    load_model(out)


def test_a_signal_while_the_progress_display_closes_waits_for_its_line(monkeypatch):
    """A Ctrl-C that lands as the progress display writes its last line used to cut it, and
    the command's 'interrupted; ...' report then continued the bar's line."""
    import io

    from rich.console import Console
    from rich.progress import Progress

    from hamgrav import cli

    closing = Progress.stop

    def stop(self):
        os.kill(os.getpid(), signal.SIGINT)  # handled at the next instruction of this thread
        closing(self)

    monkeypatch.setattr(Progress, "stop", stop)
    out = io.StringIO()
    monkeypatch.setattr(cli, "err", Console(file=out))
    with pytest.raises(KeyboardInterrupt), cli._progress() as bar:
        bar.add_task("fitting", total=2)
    assert out.getvalue().endswith("\n") and "fitting" in out.getvalue()

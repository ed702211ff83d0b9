"""Run ``hamgrav`` commands in forked children and signal them at given times (for
``tests/test_kill.py``).

Each child is a fork of this process, which has imported the command line once and run
nothing else (no threads to inherit), so a run costs the command's work, not Python's and the
libraries' start (a second and a half each, which 100 runs cannot afford). Requests are JSON
lines on stdin: ``{"args": [...], "log": path, "kill_after": seconds or null, "signal": n,
"after_file": path or null}`` (with ``after_file``, the ``kill_after`` seconds count from the
moment that file appears, not from the start); the answer to each is a JSON line
``{"status": exit status, or -signal when the signal ended the child, "seconds": how long it
ran}``.
"""

import json
import os
import select
import signal
import sys
import time

from hamgrav.cli import main as hamgrav


def _child(args: list[str], log: str) -> None:
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.stdin.close()
    try:
        hamgrav(args)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:
        import traceback

        traceback.print_exc()
        code = 1
    else:
        code = 0
    # the command has returned: a signal now (a loaded machine delivers one that late) ends
    # the child by the default action, as it would a process leaving, not as a traceback of
    # this harness's flush
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _wait(pid: int, timeout: float | None) -> int | None:
    """The child's wait status once it ends within ``timeout`` seconds (None: no limit)."""
    if timeout is None:
        return os.waitpid(pid, 0)[1]
    if hasattr(os, "pidfd_open"):
        fd = os.pidfd_open(pid)
        try:
            ready, _, _ = select.select([fd], [], [], timeout)
        finally:
            os.close(fd)
        return os.waitpid(pid, 0)[1] if ready else None
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return status
        time.sleep(0.002)
    return None


def _wait_for_file(pid: int, path: str) -> int | None:
    """None once ``path`` exists, polled every millisecond; the child's wait status if it
    ends first."""
    while not os.path.exists(path):
        status = _wait(pid, 0.001)
        if status is not None:
            return status
    return None


def main() -> None:
    # as in a command started from a terminal, whatever the test runner was started as (a
    # shell's background job ignores SIGINT, and its children inherit that)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    for line in sys.stdin:
        request = json.loads(line)
        start = time.monotonic()
        pid = os.fork()
        if pid == 0:
            _child(request["args"], request["log"])
        status = None
        if request.get("after_file"):
            status = _wait_for_file(pid, request["after_file"])
        if status is None:
            status = _wait(pid, request.get("kill_after"))
        if status is None:
            os.kill(pid, request["signal"])
            status = _wait(pid, None)
        code = os.waitstatus_to_exitcode(status)
        answer = {"status": code, "seconds": time.monotonic() - start}
        sys.stdout.write(json.dumps(answer) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    main()

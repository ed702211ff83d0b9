"""Errors a user can act on.

Every exception hamgrav raises because of the user's input, data or environment derives from
:class:`HamgravError`; its message names the problem, the file or option, and the fix. The
command line reports these in one line and exits with status 2. Anything else (a plain
``ValueError``, ``KeyError``...) is a bug in hamgrav: the command line says so, asks for a
report, and shows the traceback with ``--debug``. :class:`HamgravWarning` marks input that is
used but deserves attention (an old file without a checksum, more parameters than
observations); the command line prints it in one line.
"""

from __future__ import annotations

__all__ = [
    "HamgravError",
    "InputError",
    "BodyDataError",
    "DatasetError",
    "SimulationError",
    "PropagationError",
    "DiskError",
    "HamgravWarning",
]


class HamgravError(Exception):
    """Base of the errors caused by input, data or environment (not by a bug)."""


class InputError(HamgravError, ValueError):
    """An argument, option or configuration value is invalid."""


class BodyDataError(HamgravError, RuntimeError):
    """A body file is missing or malformed."""


class DatasetError(HamgravError, RuntimeError):
    """A dataset file is missing, truncated, corrupted or of another kind."""


class SimulationError(HamgravError, RuntimeError):
    """A campaign cannot be simulated as asked (e.g. every draw of an orbit impacts)."""


class PropagationError(HamgravError, RuntimeError):
    """A trajectory could not be propagated under a model (it diverged or became stiff)."""


class DistributedError(HamgravError, RuntimeError):
    """A cluster could not compute part of a fit (its workers gone, or a chunk of arcs lost
    more often than the scheduler retries); the fit stops like an interrupted one."""


class DiskError(HamgravError, RuntimeError):
    """A file could not be written because of the disk or its limits (full, over quota, a
    file-size limit, an I/O error, read-only), not because of hamgrav or its input.

    ``path`` is the file that was being written (never its temporary ``.part``), ``reason``
    the disk's error in words with its errno name, ``fix`` what to do.
    """

    def __init__(self, path, reason: str, fix: str):
        self.path, self.reason, self.fix = path, reason, fix
        super().__init__(f"cannot write {path}: {reason}; {fix}")

    def __reduce__(self):  # picklable (Dask workers), though __init__ takes three arguments
        return type(self), (self.path, self.reason, self.fix)


class HamgravWarning(UserWarning):
    """Input is used as given but deserves the user's attention (the message says why)."""

"""Writing files safely: to a temporary file beside the target, moved into place on success.

A write that fails for any reason (an error, a full disk, Ctrl-C or SIGTERM turned into an
exception) removes its temporary ``.part`` file; the moments that no ``try`` can cover (between
creating the temporary file and knowing its name, between the rename and forgetting the
name) run with SIGINT and SIGTERM held, and act on them just after. A write the disk refuses
(full, quota, file-size limit, I/O error, read-only) raises :class:`~hamgrav.errors.DiskError`
naming the file, in one line. Files that belong together (a results folder, one OEM file per
orbit) are written inside :func:`written_together`: all of them, or none.

Only regular files are replaced. A symbolic link at the target is refused rather than
replaced by a plain file (which would silently cut the link) or written through (which would
change a file elsewhere); a folder, device, FIFO or socket is refused too.
"""

from __future__ import annotations

import errno
import os
import signal
import tempfile
import threading
import tomllib
from collections.abc import Mapping
from contextlib import contextmanager
from pathlib import Path

from .errors import DatasetError, DiskError, InputError

__all__ = [
    "atomic_path",
    "check_output",
    "check_writable_folder",
    "disk_error",
    "make_folder",
    "read_toml",
    "remove_partial_files",
    "same_file",
    "signals_held",
    "written_together",
]

#: The errors of a write that the disk, not hamgrav or its input, causes: errno -> (what it
#: means, what to do).
_DISK_ERRORS = {
    errno.ENOSPC: ("no space left on the device", "free some space or write elsewhere"),
    errno.EDQUOT: ("disk quota exceeded", "free some space in your quota or write elsewhere"),
    errno.EFBIG: (
        "file too large for a file-size limit (ulimit -f) or the file system",
        "raise the limit or write elsewhere",
    ),
    errno.EIO: ("input/output error", "check the disk (dmesg) or write elsewhere"),
    errno.EROFS: ("read-only file system", "write elsewhere"),
}

#: Temporary files of writes in progress; see :func:`remove_partial_files`.
_PARTS: set[Path] = set()
#: Per thread, the open :func:`written_together` blocks (innermost last), each a list of
#: ("move", temporary, final) and ("folder", created, None) entries.
_TOGETHER = threading.local()


def check_output(
    path: str | os.PathLike,
    what: str = "output",
    inputs: Mapping[str, str | os.PathLike | None] | None = None,
) -> Path:
    """Refuse an output path that cannot be written atomically, before any work: its folder
    must exist and be writable, anything already at ``path`` must be a regular file
    (replaced), and it must not be one of the command's ``inputs`` (name -> path; None
    entries are skipped), which the output would replace. Raises :class:`InputError` naming
    ``what`` (e.g. an option) and the fix."""
    path = Path(path)
    if path.is_symlink():
        raise InputError(
            f"{what} {path} is a symbolic link (to {os.readlink(path)}); hamgrav replaces "
            "outputs atomically and will not cut the link: write to the link's target "
            "directly, or remove the link"
        )
    if path.is_dir():
        raise InputError(f"{what} {path} is a folder; give a file name (e.g. {path}/out.h5)")
    if path.exists() and not path.is_file():
        raise InputError(
            f"{what} {path} exists and is not a regular file (a device, FIFO or socket); "
            "give the path of a regular file"
        )
    for name, source in (inputs or {}).items():
        if source is not None and same_file(path, source):
            raise InputError(
                f"{what} {path} is also the input {name}; writing it would replace that "
                "file: give another output path"
            )
    if not path.parent.is_dir():
        if path.parent.exists():
            raise InputError(
                f"{what} {path}: {path.parent} is a file, not a folder; give a path in a folder"
            )
        raise InputError(
            f"{what}: folder {path.parent} does not exist; create it first (mkdir -p {path.parent})"
        )
    check_writable_folder(path.parent, what)
    return path


def check_writable_folder(folder: str | os.PathLike, what: str = "output") -> None:
    """Refuse a folder hamgrav cannot create files in (read-only file system, permissions),
    or, when ``folder`` does not exist yet, whose nearest existing parent is so."""
    folder = Path(folder)
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"{what} {folder}: {existing} is a file, not a folder; give a folder path")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(
            f"{what}: cannot write in folder {existing} (read-only or no permission); "
            "choose another folder"
        )


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether paths ``a`` and ``b`` are the same directory entry, so that replacing one
    replaces the other: symbolic links, ``..`` and relative paths resolved, and other
    spellings of one entry on a case-insensitive file system. Two hard links to one file
    are not (an atomic write replaces only its own entry)."""
    a, b = Path(a), Path(b)
    try:
        if a.resolve() == b.resolve():
            return True
        if a.exists() and b.exists() and os.path.samefile(a, b):
            return os.stat(a).st_nlink == 1  # one inode, one entry: the same entry
    except OSError:
        return False
    return False


def disk_error(exc: BaseException, path: str | os.PathLike) -> DiskError | None:
    """``exc`` as a :class:`DiskError` naming ``path`` when it is an OSError of the disk
    (ENOSPC, EDQUOT, EFBIG, EIO, EROFS), else None."""
    code = exc.errno if isinstance(exc, OSError) else None
    if code not in _DISK_ERRORS:
        return None
    meaning, fix = _DISK_ERRORS[code]
    return DiskError(path, f"{meaning} ({errno.errorcode[code]})", fix)


@contextmanager
def signals_held():
    """Hold SIGINT and SIGTERM for the block, then act on them as their handlers would have.

    For the few steps of a write that must not be cut in two (see the module's docstring):
    a handler that raises (KeyboardInterrupt) would leave a file that nothing removes. Only
    the main thread runs signal handlers, so elsewhere this holds nothing; a signal whose
    handler was not set from Python is left alone.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {}
    try:
        for signum in (signal.SIGINT, signal.SIGTERM):
            handler = signal.getsignal(signum)
            if handler is not None and handler is not signal.SIG_IGN:
                previous[signum] = signal.signal(signum, lambda s, _: caught.append(s))
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in dict.fromkeys(caught):
            handler = previous[signum]
            if callable(handler):
                handler(signum, None)
            else:  # SIG_DFL: the default action (SIGTERM ends the process) after all
                signal.raise_signal(signum)


def remove_partial_files() -> None:
    """Remove the temporary files of writes still in progress. A last resort for the
    command line after an interrupt: a second signal that arrives while a failed write
    cleans up can cut that clean-up short."""
    with signals_held():
        for tmp in list(_PARTS):
            tmp.unlink(missing_ok=True)
            _PARTS.discard(tmp)


def _flush(tmp: Path) -> None:
    """Force the bytes of ``tmp`` to the disk: some file systems (NFS, and any disk's
    delayed I/O errors) report a full disk or a failed write only now, not at write()."""
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ""):
    """Yield a temporary path beside ``path``; move it into place only if the block succeeds,
    so that no half-written file is ever left at ``path``, and no temporary file either.
    A disk error (of the block's writes or of the move) raises :class:`DiskError`."""
    path = Path(path)
    if not path.parent.is_dir():
        raise DatasetError(f"output folder {path.parent} does not exist; create it first")
    check_output(path)
    tmp = None
    try:
        with signals_held():  # the file and its name in _PARTS, or neither
            fd, name = tempfile.mkstemp(
                prefix=f".{path.name}.", suffix=suffix + ".part", dir=path.parent
            )
            tmp = Path(name)
            _PARTS.add(tmp)
            os.close(fd)
            umask = os.umask(0)
            os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes owner-only files; final files follow umask
        yield tmp
        _flush(tmp)
        with signals_held():  # moved (or handed on) and forgotten, or still a .part to remove
            if _open_together():
                _open_together()[-1].append(("move", tmp, path))
            else:
                os.replace(tmp, path)
                _PARTS.discard(tmp)
            tmp = None
    except BaseException as exc:
        if tmp is not None:
            with signals_held():
                tmp.unlink(missing_ok=True)
                _PARTS.discard(tmp)
        error = disk_error(exc, path)
        if error is not None:
            raise error from None
        raise


def _open_together() -> list:
    if not hasattr(_TOGETHER, "stack"):
        _TOGETHER.stack = []
    return _TOGETHER.stack


@contextmanager
def written_together():
    """Write a set of files all or none: the files :func:`atomic_path` writes in the block
    (in this thread) stay temporary files until the block ends, then are moved into place
    together; if the block fails, none is, and the folders :func:`make_folder` created in it
    are removed again when empty. Nested blocks join the outermost one."""
    stack = _open_together()
    entries: list = []
    stack.append(entries)
    try:
        yield
    except BaseException:
        with signals_held():
            stack.pop()
            _undo(entries)
        raise
    with signals_held():
        stack.pop()
        if stack:
            stack[-1].extend(entries)
            return
        pending = [e for e in entries if e[0] == "move"]
        try:
            while pending:
                _, tmp, path = pending[0]
                os.replace(tmp, path)
                _PARTS.discard(tmp)
                pending.pop(0)
        except OSError as exc:  # a rename refused: the rest stay unwritten
            _undo(pending)
            error = disk_error(exc, pending[0][2])
            if error is not None:
                raise error from None
            raise


def _undo(entries: list) -> None:
    """Remove the temporary files of ``entries`` and, when empty, the folders created."""
    for kind, made, _ in reversed(entries):
        if kind == "move":
            made.unlink(missing_ok=True)
            _PARTS.discard(made)
        else:
            try:
                made.rmdir()
            except OSError:  # not empty: it holds files of others
                pass


def make_folder(folder: str | os.PathLike) -> Path:
    """Create ``folder`` and its missing parents (inside :func:`written_together`, they are
    removed again if the block fails); a disk error raises :class:`DiskError`."""
    folder = Path(folder)
    missing = []
    parent = folder
    while not parent.exists() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    for made in reversed(missing):
        try:
            made.mkdir(exist_ok=True)
        except OSError as exc:
            error = disk_error(exc, made)
            if error is not None:
                raise error from None
            raise
        if _open_together():
            _open_together()[-1].append(("folder", made, None))
    return folder


def read_toml(path: str | os.PathLike) -> dict:
    """The table of a TOML file; a missing or malformed file raises :class:`InputError`."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a folder, not a TOML file; pass the file itself")
    if not path.is_file():
        raise InputError(f"file not found: {path}")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror})") from None

"""Writing files safely: to a temporary file beside the target, moved into place on success.

Only regular files are replaced. A symbolic link at the target is refused rather than
replaced by a plain file (which would silently cut the link) or written through (which would
change a file elsewhere); a folder, device, FIFO or socket is refused too.
"""

from __future__ import annotations

import os
import tempfile
import tomllib
from collections.abc import Mapping
from contextlib import contextmanager
from pathlib import Path

from ..errors import DatasetError, InputError

__all__ = ["atomic_path", "check_output", "check_writable_folder", "read_toml", "same_file"]


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


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ""):
    """Yield a temporary path beside ``path``; move it into place only if the block succeeds,
    so that no half-written file is ever left at ``path``."""
    path = Path(path)
    if not path.parent.is_dir():
        raise DatasetError(f"output folder {path.parent} does not exist; create it first")
    check_output(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix + ".part", dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes owner-only files; final files follow umask
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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

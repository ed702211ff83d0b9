"""What every hamgrav HDF5 file shares: a checksum of the whole file, verified before HDF5
reads a byte of it, checksummed datasets, and reading with one-line errors naming the file.

Integrity has two layers. The file starts with a 512-byte HDF5 user block (bytes HDF5 itself
ignores) holding ``hamgrav-sha256 <hex>``: the SHA-256 of every byte after the user block.
A reader verifies it before the file is handed to HDF5, because HDF5 trusts its own metadata:
a single flipped bit in a file's global heap made the HDF5 library loop forever (found by
``tests/test_fuzz.py``). A truncated, damaged or edited file is refused with one line.
Every non-empty dataset is also written with the fletcher32 filter, so that HDF5 refuses a
damaged dataset of a file whose user block was lost.

A file is built in memory and written to its path with plain writes (:func:`create`): HDF5
2.0 writing to a full disk printed its errors from the object destructors and then crashed
the interpreter (a segmentation fault in ``File.close``), so HDF5 never writes to a disk
here, and a full disk is an ordinary ``OSError`` of one write.

Files written before hamgrav wrote the user block (the HDF5 signature at byte 0) are read
with a :class:`~hamgrav.errors.HamgravWarning` that their integrity cannot be checked; every
value is still checked by its reader. A file edited in place (with h5py, say) no longer
matches its checksum and is refused: write it again with hamgrav instead.
"""

from __future__ import annotations

import hashlib
import io
import os
import warnings
from contextlib import contextmanager
from pathlib import Path

import h5py
import numpy as np

from ..errors import DatasetError, HamgravWarning

__all__ = [
    "READ_ERRORS",
    "USERBLOCK",
    "attribute",
    "body_origin",
    "create",
    "number_attribute",
    "open_for_reading",
    "write_array",
]

#: Size of the user block holding the file checksum (the smallest HDF5 allows).
USERBLOCK = 512
_MAGIC = b"hamgrav-sha256 "
_CHUNK = 1 << 20

#: What h5py, numpy and json raise on a malformed file. A reader turns these into one-line
#: :class:`~hamgrav.errors.DatasetError` messages; they never signal a bug of the reader
#: because the reader only ever sees them on input it did not write.
READ_ERRORS = (
    OSError,
    KeyError,
    ValueError,
    TypeError,
    AttributeError,
    IndexError,
    RuntimeError,
    ArithmeticError,
    MemoryError,
)


@contextmanager
def create(path: str | os.PathLike):
    """Yield a new HDF5 file (open for writing, in memory); when the block ends, write it to
    ``path`` with its checksum in the user block. The file is held in memory twice for a
    moment (HDF5's image, then the bytes written): arcs files are tens of megabytes."""
    buffer = io.BytesIO()
    with h5py.File(buffer, "w", userblock_size=USERBLOCK) as f:
        yield f
    image = buffer.getbuffer()
    try:
        stamp = _MAGIC + hashlib.sha256(image[USERBLOCK:]).hexdigest().encode() + b"\n"
        with open(path, "wb") as fh:
            fh.write(stamp.ljust(USERBLOCK, b"\0"))
            fh.write(image[USERBLOCK:])
    finally:
        image.release()


def write_array(group: h5py.Group, name: str, data) -> None:
    """Write ``data`` as dataset ``name`` of ``group``, with the fletcher32 checksum filter
    (HDF5 cannot filter scalar or empty datasets: those are written plain)."""
    arr = np.asarray(data)
    if arr.ndim and arr.size:
        group.create_dataset(name, data=arr, fletcher32=True)
    else:
        group.create_dataset(name, data=arr)


def _body_digest(fh) -> str:
    """SHA-256 (hex) of the bytes after the user block of the open binary file ``fh``."""
    fh.seek(USERBLOCK)
    h = hashlib.sha256()
    while chunk := fh.read(_CHUNK):
        h.update(chunk)
    return h.hexdigest()


_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _check_file(path: Path, kind: str, fix: str, error) -> bool:
    """Verify the user-block checksum of ``path`` before HDF5 parses it: True when it holds
    one and it matches, False for a file without a user block (HDF5 signature at byte 0:
    written by an older hamgrav); a file with one whose stamp is unreadable is damaged."""
    damaged = (
        f"{path} is truncated, corrupted or was edited: its bytes do not match the checksum "
        f"hamgrav wrote with it; {fix}"
    )
    with open(path, "rb") as fh:
        head = fh.read(USERBLOCK + len(_SIGNATURE))
        if head.startswith(_MAGIC):
            stored = head[len(_MAGIC) : len(_MAGIC) + 64].decode("ascii", "replace")
            if stored != _body_digest(fh):
                raise error(damaged)
            return True
    if head[USERBLOCK:] == _SIGNATURE:
        raise error(damaged)
    if not head.startswith(_SIGNATURE):
        raise error(
            f"{path} is truncated, corrupted or not a hamgrav {kind} (not an HDF5 file); {fix}"
        )
    return False


@contextmanager
def open_for_reading(
    path: str | os.PathLike, kind: str, fix: str, error=DatasetError, fmt: str | None = None
):
    """Open the HDF5 file at ``path`` for reading once its checksum is verified; a missing
    path, a folder, a damaged file or one that is not HDF5 raises ``error`` naming ``path``,
    what was expected (``kind``) and ``fix``. A file without a checksum whose ``format``
    attribute is ``fmt`` (a hamgrav file of an older version) is read with a
    :class:`~hamgrav.errors.HamgravWarning`; other files are left to the reader's refusal."""
    path = Path(path)
    if path.is_dir():
        raise error(f"{path} is a folder; pass the {kind} itself")
    if not path.is_file():
        raise error(f"{kind} not found: {path}")
    try:
        sealed = _check_file(path, kind, fix, error)
    except OSError as exc:
        raise error(f"{path} cannot be read ({exc.strerror}); check its permissions") from None
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise error(
            f"{path} is truncated, corrupted or not a hamgrav {kind} (not readable as HDF5: "
            f"{exc}); {fix}"
        ) from None
    try:
        found = f.attrs.get("format")
        found = found.decode() if isinstance(found, bytes) else found
        if not sealed and (fmt is None or found == fmt):
            warnings.warn(
                f"{path} has no hamgrav checksum (written by an older hamgrav): its "
                f"integrity cannot be verified; {fix} to add one",
                HamgravWarning,
                stacklevel=3,
            )
        yield f
    finally:
        f.close()


def body_origin(value, error: type[Exception]) -> tuple[float, float, float]:
    """The ``body_origin_m`` attribute's ``value`` [m, mesh frame] as three floats; raises
    ``error`` with a one-line message (the array's shape, or its values when not finite)."""
    origin = np.asarray(value, dtype=float)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        got = f"shape {origin.shape}" if origin.shape != (3,) else str(origin.tolist())
        raise error(f"attribute 'body_origin_m' must be 3 finite numbers, got {got}")
    return tuple(float(v) for v in origin)


def attribute(obj, name: str, error: type[Exception]):
    """Attribute ``name`` of an HDF5 file, group or dataset, bytes decoded to text; raises
    ``error`` when it is missing."""
    try:
        value = obj.attrs[name]
    except KeyError:
        raise error(f"attribute {name!r} is missing") from None
    return value.decode() if isinstance(value, bytes) else value


def number_attribute(obj, name: str, kind, error: type[Exception]):
    """Attribute ``name`` converted by ``kind`` (float, int); raises ``error`` naming the
    attribute, in one line, when it is missing or not a number."""
    value = attribute(obj, name, error)
    try:
        return kind(value)
    except (TypeError, ValueError, OverflowError):
        shown = f"an array of shape {value.shape}" if isinstance(value, np.ndarray) else repr(value)
        raise error(f"attribute {name!r} must be a number, got {shown[:60]}") from None

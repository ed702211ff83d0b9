"""What every hamgrav HDF5 file shares: checksummed datasets, a digest of the whole content,
and reading with one-line errors that name the file.

Integrity has two layers. Every non-empty dataset is written with the fletcher32 filter, so
HDF5 itself refuses a dataset whose bytes changed. Attributes have no such filter, so the
root attribute ``content_sha256`` holds a SHA-256 of every attribute and dataset in the file
(names, dtypes, shapes and bytes, in sorted order); a reader recomputes it. Files written
before the digest existed have no ``content_sha256``: they are read with a
:class:`~hamgrav.errors.HamgravWarning` that their integrity cannot be checked.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from contextlib import contextmanager
from pathlib import Path

import h5py
import numpy as np

from ..errors import DatasetError, HamgravWarning

__all__ = [
    "DIGEST_ATTR",
    "READ_ERRORS",
    "content_digest",
    "open_for_reading",
    "seal",
    "verify",
    "write_array",
]

#: Root attribute holding the SHA-256 of the file's content (see the module docstring).
DIGEST_ATTR = "content_sha256"

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
)


def write_array(group: h5py.Group, name: str, data) -> None:
    """Write ``data`` as dataset ``name`` of ``group``, with the fletcher32 checksum filter
    (HDF5 cannot filter scalar or empty datasets: those are written plain, and the content
    digest still covers them)."""
    arr = np.asarray(data)
    if arr.ndim and arr.size:
        group.create_dataset(name, data=arr, fletcher32=True)
    else:
        group.create_dataset(name, data=arr)


def _canonical(value) -> bytes:
    """Bytes of an attribute or dataset value that are the same after an HDF5 round trip
    (Python ints and floats are stored as 64-bit numbers, strings as UTF-8)."""
    if isinstance(value, bytes):
        return b"s" + value
    if isinstance(value, str):
        return b"s" + value.encode("utf-8")
    arr = np.asarray(value)
    if arr.dtype.kind in "SUO":
        items = [v.decode() if isinstance(v, bytes) else str(v) for v in arr.ravel().tolist()]
        return b"S" + repr((arr.shape, items)).encode("utf-8")
    kind = {"b": np.uint8, "i": np.int64, "u": np.uint64, "f": np.float64, "c": np.complex128}
    if arr.dtype.kind not in kind:
        raise TypeError(f"cannot digest values of dtype {arr.dtype}")
    canon = np.ascontiguousarray(arr, dtype=kind[arr.dtype.kind])
    return arr.dtype.kind.encode() + repr(arr.shape).encode() + canon.tobytes()


def content_digest(f: h5py.File) -> str:
    """SHA-256 (hex) of every attribute (except :data:`DIGEST_ATTR`) and dataset of ``f``."""
    h = hashlib.sha256()

    def add(name: str, obj) -> None:
        for key in sorted(obj.attrs):
            if obj.name == "/" and key == DIGEST_ATTR:
                continue
            h.update(f"attr {name}:{key}\0".encode())
            h.update(_canonical(obj.attrs[key]))
        if isinstance(obj, h5py.Dataset):
            h.update(f"data {name}\0".encode())
            h.update(_canonical(obj[()]))

    add("/", f)
    names: list[str] = []
    f.visit(names.append)
    for name in sorted(names):
        add(name, f[name])
    return h.hexdigest()


def seal(f: h5py.File) -> None:
    """Store the content digest of ``f`` (open for writing, complete) in its root attribute."""
    f.flush()
    f.attrs[DIGEST_ATTR] = content_digest(f)


def verify(f: h5py.File, path: Path, kind: str, fix: str) -> None:
    """Check the content digest of ``f`` (read from ``path``): a mismatch raises
    :class:`~hamgrav.errors.DatasetError`; a file without a digest (written before hamgrav
    stored one) is accepted with a :class:`~hamgrav.errors.HamgravWarning`."""
    stored = f.attrs.get(DIGEST_ATTR)
    if stored is None:
        warnings.warn(
            f"{path} has no content checksum (written by an older hamgrav): its integrity "
            f"cannot be verified; {fix} to add one",
            HamgravWarning,
            stacklevel=3,
        )
        return
    stored = stored.decode() if isinstance(stored, bytes) else str(stored)
    if stored != content_digest(f):
        raise DatasetError(
            f"{path} is corrupted: its content does not match the checksum written with it "
            f"(a changed or damaged {kind}); {fix}"
        )


@contextmanager
def open_for_reading(path: str | os.PathLike, kind: str, fix: str, error=DatasetError):
    """Open the HDF5 file at ``path`` for reading; a missing path, a folder or a file that is
    not HDF5 raises ``error`` naming ``path``, what was expected (``kind``) and ``fix``."""
    path = Path(path)
    if path.is_dir():
        raise error(f"{path} is a folder; pass the {kind} itself")
    if not path.is_file():
        raise error(f"{kind} not found: {path}")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise error(
            f"{path} is truncated, corrupted or not a hamgrav {kind} (not readable as HDF5: "
            f"{exc}); {fix}"
        ) from None
    try:
        yield f
    finally:
        f.close()

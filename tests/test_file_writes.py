"""atomic_path and written_together: a write that fails, is refused by the disk or is
interrupted at any moment leaves the old file or the new one, never a part of one."""

import errno
import os
import signal
import tempfile

import pytest

from hamgrav import files
from hamgrav.errors import DiskError
from hamgrav.files import atomic_path, make_folder, signals_held, written_together


@pytest.fixture
def sigint_handled():
    """Python's own SIGINT handler, as in a terminal (a shell's background job ignores it)."""
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, outer)


def _names(folder):
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize(
    ("code", "said"),
    [
        (errno.ENOSPC, "no space left on the device (ENOSPC); free some space or write elsewhere"),
        (errno.EDQUOT, "disk quota exceeded (EDQUOT)"),
        (errno.EFBIG, "file-size limit (ulimit -f) or the file system (EFBIG)"),
        (errno.EIO, "input/output error (EIO); check the disk"),
        (errno.EROFS, "read-only file system (EROFS)"),
    ],
)
def test_a_disk_error_names_the_file_and_leaves_nothing(tmp_path, code, said):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(DiskError) as info, atomic_path(target) as tmp:
        tmp.write_text("half")
        raise OSError(code, os.strerror(code))
    assert str(info.value).startswith(f"cannot write {target}: ") and said in str(info.value)
    assert "\n" not in str(info.value) and ".part" not in str(info.value)
    assert _names(tmp_path) == ["out.txt"] and target.read_text() == "old"


def test_other_os_errors_are_not_disk_errors(tmp_path):
    with pytest.raises(PermissionError), atomic_path(tmp_path / "x") as tmp:
        tmp.write_text("half")
        raise PermissionError(errno.EACCES, "denied")
    assert _names(tmp_path) == []


def test_an_error_reported_only_when_flushed_is_a_disk_error(tmp_path, monkeypatch):
    """Some disks report a failed write only at fsync (NFS, delayed I/O errors)."""

    def failing_fsync(fd):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(files.os, "fsync", failing_fsync)
    with pytest.raises(DiskError, match="input/output error"), atomic_path(tmp_path / "x") as tmp:
        tmp.write_text("all of it")
    assert _names(tmp_path) == []


@pytest.mark.parametrize("where", ["creating", "before the rename", "after the rename"])
def test_a_signal_at_the_uncovered_moments_leaves_no_part(
    tmp_path, monkeypatch, where, sigint_handled
):
    """Ctrl-C at the moments no try can cover (the temporary file made but its name not yet
    known; the rename done but the name not yet forgotten) is held until they are over."""
    umask = os.umask(0o022)
    os.umask(umask)
    target = tmp_path / "out.txt"
    target.write_text("old")
    real_mkstemp, real_replace = tempfile.mkstemp, os.replace

    def mkstemp(*args, **kwargs):
        made = real_mkstemp(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)
        return made

    def replace(src, dst):
        if where == "before the rename":
            signal.raise_signal(signal.SIGINT)
        real_replace(src, dst)
        if where == "after the rename":
            signal.raise_signal(signal.SIGINT)

    if where == "creating":
        monkeypatch.setattr(files.tempfile, "mkstemp", mkstemp)
    else:
        monkeypatch.setattr(files.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt), atomic_path(target) as tmp:
        tmp.write_text("new")
    assert _names(tmp_path) == ["out.txt"] and not files._PARTS
    assert target.read_text() == ("old" if where == "creating" else "new")
    assert os.umask(umask) == umask  # not left at 0 by a signal between the two umask calls


def test_signals_held_delivers_them_after(sigint_handled):
    reached = []
    with pytest.raises(KeyboardInterrupt), signals_held():
        signal.raise_signal(signal.SIGINT)
        reached.append(True)
    assert reached and signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_files_written_together_are_all_or_none(tmp_path):
    kept = tmp_path / "kept.json"
    kept.write_text("old")
    folder = tmp_path / "new" / "run"
    with pytest.raises(DiskError), written_together():
        make_folder(folder)
        with atomic_path(folder / "a.json") as tmp:
            tmp.write_text("a")
        with atomic_path(kept) as tmp:
            tmp.write_text("new")
        assert not (folder / "a.json").exists()  # not yet in place
        with atomic_path(folder / "b.png") as tmp:
            raise OSError(errno.ENOSPC, "No space left on device")
    assert _names(tmp_path) == ["kept.json"] and kept.read_text() == "old"
    with written_together():
        make_folder(folder)
        for name in ("a.json", "b.png"):
            with atomic_path(folder / name) as tmp:
                tmp.write_text(name)
    assert _names(folder) == ["a.json", "b.png"] and not files._PARTS


def test_an_interrupted_set_of_files_leaves_none(tmp_path, sigint_handled):
    with pytest.raises(KeyboardInterrupt), written_together():
        for name in ("a", "b"):
            with atomic_path(tmp_path / name) as tmp:
                tmp.write_text(name)
        signal.raise_signal(signal.SIGINT)
    assert _names(tmp_path) == [] and not files._PARTS

"""Writing files safely: atomically, with the user's umask, never over a command's own input,
and with every output location checked before any work starts."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import BinaryIO

from tron1cli.errors import UsageError


def _read_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: the process's umask, read once at import (reading it means setting it; threads may not have
#: started yet at import time)
UMASK = _read_umask()


def temp_prefix(path: Path) -> str:
    """The name prefix of the temp files an atomic write of ``path`` makes beside it."""
    return f".{Path(path).name}."


def atomic_write(path: Path, write: Callable[[BinaryIO], None], fsync: bool = True) -> None:
    """Write ``path`` through ``write(f)`` into a temp file beside it, then rename it into place.

    The file gets mode 0666 minus the umask, like any file the user writes (a bare temp file would
    be 0600). A failed or interrupted write removes its temp file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temp_prefix(path), suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~UMASK)
        with os.fdopen(fd, "wb") as f:
            write(f)
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(e, OSError) and e.filename is None and e.errno is not None:
            # a write that failed (a disk full) names no file: name the one being written
            raise OSError(e.errno, e.strerror or str(e), str(path)) from e
        raise


def write_file(path: Path, data: bytes | str, fsync: bool = False) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` atomically: a failed write (a disk that fills)
    leaves the earlier file as it was, never a file cut short."""
    blob = data.encode() if isinstance(data, str) else bytes(data)
    atomic_write(Path(path), lambda f: f.write(blob), fsync=fsync)


def clean_stale_temps(folder: Path, prefix: str = ".") -> list[Path]:
    """Remove the temp files (``<prefix>*.tmp``) a killed atomic write left in ``folder``."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    gone = []
    for p in folder.glob(f"{prefix}*.tmp"):
        if p.is_file() and p.name.startswith("."):
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone


def same_path(a: Path | str, b: Path | str) -> bool:
    """Whether ``a`` and ``b`` name the same file (links and relative paths resolved)."""
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):  # a symbolic link loop: compare the paths as given
        return os.path.abspath(a) == os.path.abspath(b)


def _check_can_create(folder: Path, option: str, shown: Path) -> None:
    """UsageError unless ``folder`` is, or can be made, a writable folder."""
    existing = Path(folder)
    while not existing.exists() and existing != existing.parent:
        if existing.is_symlink():  # a dangling link: mkdir would fail on it
            raise UsageError(f"{option} {shown}: {existing} is a broken link")
        existing = existing.parent
    if not existing.is_dir():
        raise UsageError(f"{option} {shown}: cannot make a folder there, {existing} is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {shown}: no permission to write in {existing}")
    try:  # os.access passes for root everywhere; some places (/proc, /sys) still refuse a folder
        os.rmdir(tempfile.mkdtemp(prefix=".tron1-probe-", dir=existing))
    except OSError as e:
        raise UsageError(f"{option} {shown}: cannot create anything in {existing} ({e.strerror})") from e


def check_output_file(path: Path | str, option: str, inputs: Iterable[Path | str] = ()) -> bool:
    """Check an output file before the work: not a folder, not one of ``inputs``, its folder
    writable or creatable. Returns whether the file exists already (it will be replaced)."""
    path = Path(path)
    for src in inputs:
        if same_path(path, src):
            raise UsageError(
                f"{option} {path} is the command's own input {src}; writing there would destroy it"
            )
    if path.is_dir():
        raise UsageError(f"{option} {path} is a folder; give a file name")
    _check_can_create(path.parent, option, path)
    return path.exists()


def check_output_dir(path: Path | str, option: str, inputs: Iterable[Path | str] = ()) -> bool:
    """Check an output folder before the work: not a file, not holding an input's place,
    writable or creatable. Returns whether it exists already."""
    path = Path(path)
    for src in inputs:
        if same_path(path, src):
            raise UsageError(f"{option} {path} is the command's own input {src}")
    if path.exists() and not path.is_dir():
        raise UsageError(f"{option} {path} is a file, not a folder")
    _check_can_create(path, option, path)
    return path.exists()

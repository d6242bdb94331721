"""Writing files so that a crash or a kill never leaves a torn one; output directories.

:func:`atomic_write` is the one way collavn writes a file that another run will read
(episode files, saved scenes, checkpoints): a uniquely named temporary file beside the
target, flushed and ``fsync``-ed, then renamed over it. A failure at any point leaves
the target as it was and no temporary file behind; only a hard kill (SIGKILL, power
loss) mid-write can leave one, and ``clean_stale=True`` removes such leftovers of the
same target on the next write.

:func:`prepare_output_dir` is the one rule for a command's output directory: refused if
it is a file, not writable, or already holds earlier results — unless the caller
continues them (``resume``) or asks to start over (``overwrite``: the old directory is
moved aside, never deleted). It runs before any work starts.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from collavn.errors import ConfigError


def atomic_write(path: str | Path, data: bytes | Callable[[BinaryIO], object],
                 clean_stale: bool = False) -> Path:
    """Write ``data`` (bytes, or a function writing to a binary file) to ``path`` atomically.

    Args:
        path: The target file.
        data: Its content, or a function writing it.
        clean_stale: First delete temporary files of ``path`` left by an interrupted
            earlier write. Only for targets with a single writer (a run's checkpoint):
            with several concurrent writers it would delete a write in progress.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if clean_stale:
        for stale in path.parent.glob(f".{path.name}.*.tmp"):
            with contextlib.suppress(FileNotFoundError):
                stale.unlink()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            if isinstance(data, bytes):
                f.write(data)
            else:
                data(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


def sha256_hex(data: bytes) -> str:
    """SHA-256 of ``data`` as 64 hex digits (the content checksum of our files)."""
    return hashlib.sha256(data).hexdigest()


def prepare_output_dir(path: str | Path, flag: str = "--out", *, resume: bool = False,
                       overwrite: bool = False, create: bool = True) -> Path | None:
    """Check (and create) an output directory before any work starts.

    Args:
        path: The directory.
        flag: How the user named it, for messages (``--out``).
        resume: The caller continues what the directory holds: a non-empty one is fine.
        overwrite: Start over: a non-empty directory is first moved aside to
            ``<path>.old-<YYYYmmdd-HHMMSS>`` (nothing is deleted).
        create: Create the directory, move an old one aside and probe that it is
            writable (``False``: only the checks, e.g. on non-zero distributed ranks).

    Returns:
        Where the old directory was moved, if it was.

    Raises:
        ConfigError: ``path`` is a file, cannot be created or written, or holds earlier
            results and neither ``resume`` nor ``overwrite`` is given.
    """
    path = Path(path)
    if resume and overwrite:
        raise ConfigError("--resume and --overwrite exclude each other: continue the run "
                          "or start it over")
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag} {path} is a file, not a directory")
    moved = None
    if path.is_dir() and any(path.iterdir()) and not resume:
        if not overwrite:
            raise ConfigError(
                f"{flag} {path} already holds results ({_listing(path)}); continue them "
                f"with --resume (train), start over with --overwrite (the old directory is "
                f"moved to {path.name}.old-<time>), or choose another {flag}")
        if create:
            moved = path.with_name(f"{path.name}.old-{time.strftime('%Y%m%d-%H%M%S')}")
            k = 1
            while moved.exists():
                moved, k = moved.with_name(f"{moved.name.split('~')[0]}~{k}"), k + 1
            path.rename(moved)
    if create:
        try:
            path.mkdir(parents=True, exist_ok=True)
            fd, probe = tempfile.mkstemp(dir=path, prefix=".write-test.")
            os.close(fd)
            os.unlink(probe)
        except OSError as e:
            raise ConfigError(f"cannot write to {flag} {path}: {e.strerror or e}") from e
    return moved


def check_writable_file(path: str | Path, flag: str) -> Path:
    """Refuse an output file that cannot be written (its directory is created).

    Raises:
        ConfigError: ``path`` is a directory, or its directory cannot be created or
            written.
    """
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{flag} {path} is a directory, not a file")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path.parent, prefix=".write-test.")
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise ConfigError(f"cannot write {flag} {path}: {e.strerror or e}") from e
    return path


def _listing(path: Path, most: int = 3) -> str:
    names = sorted(p.name for p in path.iterdir())
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most
                                      else "")

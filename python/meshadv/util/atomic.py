"""Atomic file writes: readers see either the old file or the complete new one, never a partial file.

The content goes to a temporary file in the destination's folder (same file system), is flushed and fsynced, gets
the usual permissions (``0666`` minus the umask, not ``mkstemp``'s ``0600``) and is renamed over the destination
with ``os.replace``. On any error the temporary file is removed and the destination is untouched.

Example:
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = write_json_atomic({"a": 1}, folder / "x.json"); (folder / "x.json").read_text()
    '{\\n  "a": 1\\n}'
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Optional, Union

__all__ = ["atomic_path", "write_bytes_atomic", "write_text_atomic", "write_json_atomic"]

PathLike = Union[str, "os.PathLike[str]"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: PathLike, *, suffix: str = ".tmp", mode: Optional[int] = None) -> Iterator[Path]:
    """A temporary path next to ``path`` to write to; moved over ``path`` when the block ends without error.

    For writers that want a file name (``np.savez``, ``PIL.Image.save``, ``mitsuba``). The folder must exist.

    Args:
        path: destination.
        suffix: suffix of the temporary name (e.g. ``".npz"`` for writers that insist on one).
        mode: permission bits of the result (default ``0o666`` minus the umask). The temporary file is ``0o600``
            while it is written, so a private file (``mode=0o600``) is never readable by others.

    Yields:
        The temporary path (the file exists, empty).
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb") as handle:
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o666 & ~_umask() if mode is None else mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: PathLike, data: bytes, *, mode: Optional[int] = None) -> Path:
    """Write ``data`` to ``path`` atomically (permission bits ``mode``, see :func:`atomic_path`); returns the path.
    The folder must exist."""
    with atomic_path(path, mode=mode) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(record: Any, path: PathLike, *, indent: int = 2) -> Path:
    """Write ``record`` as JSON to ``path`` atomically; returns the path."""
    return write_text_atomic(path, json.dumps(record, indent=indent))

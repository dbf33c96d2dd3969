"""Files written whole or not at all: a temporary file in the same directory, then an atomic rename.

A full disk (or a quota, or a file-size limit) fails a write half-way; written
in place, the file would be left cut short, and a reader could not tell it
from a whole one. The run directory (:mod:`mosd.app.files`), its figures
(:mod:`mosd.app.plots`) and ``mosd log``'s files (:mod:`mosd.app.pending`) are
written through :func:`write_atomically`.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import IO, Any, Callable, Mapping

# the process's umask (read once: os.umask can only be read by setting it); mkstemp makes files
# private, a result file is as readable as any file the user writes
_UMASK = os.umask(0)
os.umask(_UMASK)


def write_atomically(path: str | os.PathLike, write: Callable[[IO], Any], binary: bool = False) -> Path:
    """Write ``path`` with ``write(file)`` through a temporary file and an atomic rename.

    The file is complete or absent: a write that fails (disk full, quota, file
    size limit) removes the temporary file, keeps what ``path`` held before and
    raises the ``OSError``.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=path.suffix, dir=path.parent)
    try:
        with os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as out:
            write(out)
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def write_json(path: str | os.PathLike, data: Mapping[str, Any]) -> Path:
    """``data`` as indented strict JSON, atomically (:func:`write_atomically`).

    Strict: a NaN or infinite number (an undefined metric, a one-run confidence
    half-width) is written as ``null`` (:func:`mosd.metrics.json_ready`), never as the bare
    ``NaN`` that JSON parsers other than Python's reject; ``allow_nan=False`` makes a
    value that slipped through an error here rather than a file nobody else can read.
    """
    from ..metrics.summary import json_ready

    return write_atomically(path, lambda out: json.dump(json_ready(data), out, indent=2, allow_nan=False))

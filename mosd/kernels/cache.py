"""A damaged kernel cache is removed, not fatal.

numba keeps each compiled kernel in two files beside the module (``__pycache__/<module>.<kernel>-<line>.pyXY.nbi``,
its index, and ``….nbc``, the code), or under ``NUMBA_CACHE_DIR``; both are pickle streams that numba loads with
``pickle.load`` when a kernel is first called. A truncated or overwritten file (a full disk, a copy interrupted,
a cache shared between machines) then stopped the run wherever that first call was, with ``UnpicklingError:
pickle data was truncated`` (issue 50). numba writes its files whole (a temporary file renamed into place), so a
damaged file is never one being written.

:func:`repair` walks each such file's pickle opcodes with the standard library's :func:`pickletools.genops`,
which parses the stream without building any object (about 30 ms for the whole cache of 4 MB), and removes the
files that do not parse: numba then finds no cached code for that kernel and compiles it again, as on an empty
cache. One warning line says which files went and why. The check reads only mosd's own files (its package's ``__pycache__`` folders, and ``NUMBA_CACHE_DIR``).

:func:`usable_place` checks, before any kernel module is imported, that the folder numba will write the kernels'
files to takes a file of the size of the largest one (a full disk, a read-only folder, a file-size limit made the
first compile fail with ``OSError`` after its work, and a package without any writable folder failed its import
with numba's ``RuntimeError: no locator available``); when it does not, the kernels are cached in a folder of the
temporary directory instead, or, without one, the NumPy path is taken: one warning line either way.

:func:`fresh_index` says whether a kernel has an entry in that cache for its current source, from the files alone
(numba's documented ``cache=True`` files, found by name): no attribute of numba's dispatcher or cache objects is
read, so a numba release that renames those cannot break it; one that changes the files makes it answer False
(the kernel is then compiled ahead again, on the other core: slower, never wrong).
"""
from __future__ import annotations

import hashlib
import io
import os
import pickle
import pickletools
import sys
import tempfile
from pathlib import Path

#: what numba names its cache files: the index and the code of one kernel
SUFFIXES = (".nbi", ".nbc")


def cache_files(package_dir: Path | None = None) -> list[Path]:
    """mosd's numba cache files: in the ``__pycache__`` folders of the package, and those of its modules under
    ``NUMBA_CACHE_DIR``."""
    package_dir = Path(package_dir or Path(__file__).resolve().parents[1])
    found = {path for place in package_dir.rglob("__pycache__") for suffix in SUFFIXES
             for path in place.rglob(f"*{suffix}") if path.is_file()}
    override = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if override and Path(override).is_dir():
        # a shared cache holds other projects' files too: only those named after one of mosd's modules
        # (numba names a file <module>.<function>-<line>.pyXY...)
        modules = {path.stem for path in package_dir.rglob("*.py")}
        found.update(path for suffix in SUFFIXES for path in Path(override).rglob(f"*{suffix}")
                     if path.is_file() and path.name.split(".", 1)[0] in modules)
    return sorted(found)


def damaged(path: Path) -> str | None:
    """Why ``path`` is not a sequence of whole pickles (None when it is): the opcodes are parsed, nothing is built."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        return f"{type(exc).__name__}: {exc.strerror or exc}"
    if not data:
        return "empty"
    stream = io.BytesIO(data)
    try:
        while stream.tell() < len(data):  # an index is two pickles (numba's version, then the index)
            for _ in pickletools.genops(stream):
                pass
    except Exception as exc:  # noqa: BLE001 - genops raises ValueError, and others on garbage: all mean damaged
        return f"{type(exc).__name__}: {exc}"
    return None


def repair(package_dir: Path | None = None, stream=None) -> list[Path]:
    """Remove the damaged kernel cache files (one warning line on ``stream``, stderr by default); the removed paths.

    A file that cannot be removed (a read-only cache) is left, and the warning says so: numba then fails to
    load it where the kernel is first called, as before.
    """
    removed, kept, reason = [], [], ""
    for path in cache_files(package_dir):
        why = damaged(path)
        if why is None:
            continue
        reason = reason or why
        try:
            path.unlink()
            removed.append(path)
        except FileNotFoundError:  # another process removed it first
            removed.append(path)
        except OSError:
            kept.append(path)
    if removed or kept:
        place = (removed or kept)[0].parent
        text = (f"mosd: warning: {len(removed)} damaged kernel cache file(s) in {place} removed ({reason}); "
                "those kernels compile again")
        if kept:
            text += f"; {len(kept)} could not be removed (read-only): delete them by hand"
        print(text, file=stream or sys.stderr)
    return removed


def index_name(function) -> str:
    """The file name numba gives the index of cached kernel ``function`` (the Python function it compiles).

    ``<module file's stem>.<qualified name>-<first line>.py<major><minor><abiflags>.nbi``, ``<`` and ``>`` left out.
    """
    stem = Path(function.__code__.co_filename).stem
    qualname = function.__qualname__.replace("<", "").replace(">", "")
    version = f"{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, 'abiflags', '')}"
    return f"{stem}.{qualname}-{function.__code__.co_firstlineno}.py{version}.nbi"


def index_paths(function) -> list[Path]:
    """Where an index of ``function`` may be: ``NUMBA_CACHE_DIR`` (any of its folders) when set, else the
    ``__pycache__`` folder beside its source."""
    name = index_name(function)
    override = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    if override:
        return sorted(Path(override).rglob(name)) if Path(override).is_dir() else []
    path = Path(function.__code__.co_filename).parent / "__pycache__" / name
    return [path] if path.is_file() else []


def _source_stamps(source: Path) -> tuple:
    """What numba's index may record of ``source`` to tell a stale entry: its SHA-256 (numba 0.61 on) or its
    modification time and size (before)."""
    data = source.read_bytes()
    st = source.stat()
    return hashlib.sha256(data).digest(), (st.st_mtime, st.st_size)


def fresh_index(function, numba_version: str) -> bool:
    """Whether ``function`` has an index in numba's cache written by ``numba_version`` for its current source, with
    at least one compiled entry. Any file this cannot read counts as no entry (False)."""
    try:
        stamps = _source_stamps(Path(function.__code__.co_filename))
    except OSError:
        return False
    for path in index_paths(function):
        try:
            with open(path, "rb") as stream:
                if pickle.load(stream) != numba_version:  # an index is numba's version, then (stamp, entries)
                    continue
                stamp, entries = pickle.loads(stream.read())
        except Exception:  # noqa: BLE001 - a damaged or foreign file: not an entry (repair() removes damaged ones)
            continue
        if stamp in stamps and entries:
            return True
    return False


#: bytes a cache folder must take to be used: a little over the largest file numba writes for mosd's kernels
#: (paper 001's IMM filter, 0.55 MB)
PROBE_BYTES = 1 << 20


def _write_problem(folder: Path) -> str | None:
    """Why ``folder`` cannot take a file of :data:`PROBE_BYTES` (None when it can); the probe is removed."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder) as probe:
            # a local file system refuses the write itself when full (no fsync: 10 ms per process start)
            probe.write(b"\0" * PROBE_BYTES)
            probe.flush()
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    return None


def usable_place(kernels_dir: Path, environ=os.environ) -> tuple[str | None, str | None]:
    """Where numba should cache mosd's kernels: ``(folder or None, warning or None)``.

    The folder is ``NUMBA_CACHE_DIR`` when set, else numba's own ``__pycache__`` beside the kernels
    (``kernels_dir``): ``(None, None)`` when it takes :data:`PROBE_BYTES`. Otherwise a folder of the temporary
    directory that does, with a one-line warning; ``(None, warning)`` when neither does (the caller takes the
    NumPy path).
    """
    override = environ.get("NUMBA_CACHE_DIR", "").strip()
    first = Path(override) if override else Path(kernels_dir) / "__pycache__"
    why = _write_problem(first)
    if why is None:
        return None, None
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    fallback = Path(tempfile.gettempdir()) / f"mosd-numba-cache-{uid}"
    if fallback != first and _write_problem(fallback) is None:
        return str(fallback), (f"mosd: warning: kernel cache {first} cannot be written ({why}); "
                               f"kernels are cached in {fallback}")
    return None, (f"mosd: warning: kernel cache {first} cannot be written ({why}) and neither can {fallback}: "
                  "the NumPy path is used")

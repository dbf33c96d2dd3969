"""Kernels compiled ahead in a second process while this one goes on: a first run on an empty cache, on two cores.

A process compiles each numba kernel where it first calls it, one after another: on an empty cache most of a
first run's time (the filter, then the chart and the EWMA recursion of the main command). Which kernels a run
calls is known before it calls any (the app asks its components), so :func:`start` hands the ones needed
last to a second process, which compiles them on another core while this process compiles and runs the ones
needed first. numba's on-disk cache is the hand-over: the second process saves each part as it is compiled
(numba writes a cache entry under a temporary name and renames it, so a reader never sees half of one), and
this process loads it from there where it first calls it.

A kernel this process reaches while the second process still compiles it waits for it instead of compiling it
too (:class:`Ahead`: each handed-over dispatcher's public ``compile``, which numba calls on every lookup that
misses its loaded code, is wrapped, on that instance only, to wait for its part first), so no kernel is compiled
twice. If the second process fails on a part or dies, every wait ends and this process compiles what is missing,
as it would have without it; one that is stopped (SIGSTOP) or gets no CPU for :data:`STALL_S` seconds is ended
and the same happens: a wait never outlasts the second process's progress. Compiling ahead changes when a kernel
is compiled, never what is computed.

The parts (:data:`PARTS`) are whole modules (their ``warm_up``: the signatures a run calls) and, for the
filter, its two helpers alone: :func:`mosd.kernels.cubature.filter_batch` compiles its own code before it asks
for its helpers', so the filter's body compiles here while the helpers compile there.

``python -m mosd.kernels.ahead PART...`` is the second process (it reports ``ready PART`` or ``failed PART``
on stdout, one line each, and ends when its stdin closes: when the process that started it dies).
"""
from __future__ import annotations

import atexit
import importlib
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import Sequence


def _filter_helpers():
    from . import cubature

    return cubature.helper_dispatchers()


def _warm_up_filter_helpers() -> None:
    from . import cubature

    cubature.warm_up_helpers()


#: Every part a second process can compile: name -> (module, its dispatchers here, how to compile it there).
#: A module part hands over every dispatcher the module defines; ``cubature.helpers`` only the filter's helpers.
PARTS = {
    "cubature.helpers": ("cubature", _filter_helpers, _warm_up_filter_helpers),
    **{name: (name, None, None) for name in ("ewma", "wavelet", "chart", "plants", "cubature", "imm", "entropy",
                                             "projection", "decisions", "latent", "swarm")},
    "chart.denoised": ("chart", None, lambda: importlib.import_module(f"{__package__}.chart").warm_up_denoised()),
}


def _dispatchers(part: str) -> list:
    """The dispatchers of ``part`` in this process (numba's, with an on-disk cache)."""
    from . import cached_dispatchers

    module_name, chosen, _ = PARTS[part]
    if chosen is not None:
        return list(chosen())
    return cached_dispatchers(importlib.import_module(f"{__package__}.{module_name}"))


def _compile(part: str) -> None:
    """Compile ``part`` into the on-disk cache (the second process's work)."""
    module_name, _, warm = PARTS[part]
    if warm is not None:
        warm()
    else:
        importlib.import_module(f"{__package__}.{module_name}").warm_up()


def _waiting_compile(compile, wait):
    """A dispatcher's own ``compile`` (its public method, bound) that first waits for the part (``wait()``)."""

    def waiting(sig):
        wait()
        return compile(sig)

    return waiting


#: seconds the second process may go without using any CPU while this process waits for it (stopped, swapped
#: out, starved) before this process stops waiting, ends it and compiles the part itself
STALL_S = 5.0
#: seconds this process waits for one part at most, whatever the second process does
WAIT_S = 300.0


class Ahead:
    """The second process compiling ``parts`` (in order), and this process's waits for them.

    Built by :func:`start`. ``ready`` and ``failed`` say what the second process did
    with each part; :meth:`close` (idempotent) ends the process and every wait.
    """

    def __init__(self, parts: Sequence[str]):
        unknown = [p for p in parts if p not in PARTS]
        if unknown:
            raise ValueError(f"parts {unknown} are not kernel parts; allowed: {', '.join(PARTS)}")
        self.parts = tuple(parts)
        self.ready: set[str] = set()
        self.failed: dict[str, str] = {}
        self._done = {part: threading.Event() for part in self.parts}
        self._hooked: list[tuple[object, object]] = []
        from . import enabled

        if not enabled():
            raise RuntimeError("kernels are off (MOSD_KERNELS=numpy or no numba): nothing to compile")
        for part in self.parts:  # before the process starts: no lookup of a handed-over kernel escapes the wait
            for dispatcher in _dispatchers(part):
                hook = _waiting_compile(dispatcher.compile, lambda part=part: self.wait(part))
                dispatcher.compile = hook  # an instance attribute: numba's lookups call self.compile
                self._hooked.append((dispatcher, hook))
        package_parent = str(Path(__file__).resolve().parents[2])  # the directory holding mosd/
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
                 "from mosd.kernels.ahead import main; sys.exit(main(sys.argv[2:]))", package_parent, *self.parts],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        except OSError:
            self._unhook()
            raise
        self._reader = threading.Thread(target=self._read, name="mosd-kernels-ahead", daemon=True)
        self._reader.start()

    def pending(self, part: str) -> bool:
        """Whether the second process has not yet reported on ``part`` (and may still compile it)."""
        return part in self._done and not self._done[part].is_set()

    def wait(self, part: str, stall_s: float | None = None, wait_s: float | None = None) -> bool:
        """Wait until the second process has reported on ``part``; True when it compiled it.

        The wait ends early, and the second process is ended (:meth:`close`), when it has used no CPU for
        ``stall_s`` seconds (:data:`STALL_S`; a stopped process, SIGSTOP, uses none) or after ``wait_s``
        (:data:`WAIT_S`): this process then compiles the part itself.
        """
        import time

        done = self._done.get(part)
        if done is None or done.is_set():  # numba calls compile on every lookup while typing: the common case
            return part in self.ready
        stall_s = STALL_S if stall_s is None else stall_s
        deadline = time.monotonic() + (WAIT_S if wait_s is None else wait_s)
        used, since = self._cpu_seconds(), time.monotonic()
        while not done.wait(0.1):
            now, cpu = time.monotonic(), self._cpu_seconds()
            if cpu is None or cpu != used:
                used, since = cpu, now
            if now >= deadline or now - since >= stall_s:
                why = "stalled" if now - since >= stall_s else f"not done in {WAIT_S:.0f} s"
                for other in self._done:
                    if not self._done[other].is_set():
                        self.failed.setdefault(other, f"the second process {why}: compiled here")
                self.close()
                break
        return part in self.ready

    def _cpu_seconds(self) -> float | None:
        """The CPU seconds the second process has used so far (None when it cannot be read: ended)."""
        import psutil

        try:
            times = psutil.Process(self._proc.pid).cpu_times()
        except (psutil.Error, OSError):
            return None
        return times.user + times.system

    def _read(self) -> None:
        try:
            for line in self._proc.stdout:
                word, _, rest = line.strip().partition(" ")
                part, _, why = rest.partition(" ")
                if part in self._done:
                    (self.ready.add(part) if word == "ready" else self.failed.setdefault(part, why or word))
                    self._done[part].set()
        except (OSError, ValueError):  # closed under us by close()
            pass
        for part, done in self._done.items():  # the process ended: what it did not report, this one compiles
            if not done.is_set():
                self.failed.setdefault(part, "the second process ended before it")
                done.set()
        self._unhook()

    def _unhook(self) -> None:
        for dispatcher, hook in self._hooked:
            if vars(dispatcher).get("compile") is hook:
                del dispatcher.compile  # numba's own method again
        self._hooked = []

    def close(self) -> None:
        """End the second process (whatever it was doing) and every wait."""
        if self._proc.poll() is None:
            try:
                self._proc.kill()
            except OSError:  # pragma: no cover - already gone
                pass
        for stream in (self._proc.stdin, self._proc.stdout):
            try:
                stream.close()
            except (OSError, ValueError):
                pass
        self._proc.wait()
        for done in self._done.values():
            done.set()
        self._unhook()


_CURRENT: list[Ahead] = []


def start(parts: Sequence[str]) -> Ahead | None:
    """Compile ``parts`` (of :data:`PARTS`, in this order) in a second process from now on; None when none.

    This process's lookups of those kernels wait for the second process (module
    docstring). The process is ended when this one exits (and by :func:`close`).
    """
    close()
    if not parts:
        return None
    ahead = Ahead(parts)
    _CURRENT.append(ahead)
    return ahead


def close() -> None:
    """End the second process :func:`start` started, if any (idempotent)."""
    while _CURRENT:
        _CURRENT.pop().close()


def pending(part: str) -> bool:
    """Whether the second process is still compiling ``part`` (a lookup of its kernels here would wait for it)."""
    return any(ahead.pending(part) for ahead in _CURRENT)


def finish(timeout: float) -> None:
    """Let the second process finish what it compiles (at most ``timeout`` seconds), then end it.

    A run that took another path while a part compiled (the optimiser's NumPy move while the compiled move
    compiles: :func:`mosd.kernels.swarm.ready`) may end first; waiting here, after its results, leaves the part
    in numba's cache for the next run instead of killing its compilation every time.
    """
    import time

    deadline = time.monotonic() + max(0.0, timeout)
    for ahead in list(_CURRENT):
        for part in ahead.parts:
            # a part compiled at a lower priority (BACKGROUND) may get no CPU for a while on a busy machine
            ahead.wait(part, stall_s=max(STALL_S, 30.0), wait_s=max(0.0, deadline - time.monotonic()))
    close()


atexit.register(close)


def _exit_when_orphaned() -> None:
    """End this (second) process when its stdin closes: the process that started it has ended."""
    try:
        while sys.stdin.buffer.read(65536):
            pass
    except (OSError, ValueError):
        pass
    os._exit(0)


#: parts the first process does not wait for (it runs another path meanwhile: :func:`mosd.kernels.swarm.ready`):
#: compiled at a lower priority, on the CPU the run leaves idle, after the parts it waits for
BACKGROUND = ("swarm",)
BACKGROUND_NICE = 10


def compile_parts(parts: Sequence[str], report=print) -> int:
    """Compile each part in order into the cache, reporting ``ready PART`` / ``failed PART why``; the failures."""
    failed = 0
    for part in parts:
        try:
            if part not in PARTS:
                raise ValueError(f"not a kernel part (allowed: {', '.join(PARTS)})")
            if part in BACKGROUND and hasattr(os, "nice"):
                os.nice(max(0, BACKGROUND_NICE - os.nice(0)))  # once: a nice value is never raised back
            _compile(part)
            report(f"ready {part}")
        except Exception as exc:  # noqa: BLE001 - reported; the first process compiles this part itself
            failed += 1
            report(f"failed {part} {type(exc).__name__}: {' '.join(str(exc).split())}")
    return failed


def main(parts: Sequence[str]) -> int:
    """The second process: :func:`compile_parts`, ended early when the first process ends."""
    threading.Thread(target=_exit_when_orphaned, name="mosd-orphaned", daemon=True).start()
    return 1 if compile_parts(parts, report=lambda line: print(line, flush=True)) else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

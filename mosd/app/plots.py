"""Where a run's figures (:mod:`mosd.app.figures`) are drawn: a side process that keeps matplotlib off the run's.

:class:`FigureWriter` draws them in a side process: it starts with the run (before
the command line is checked when the machine has a core to spare:
:func:`start_early`), imports matplotlib and loads its fonts on the second core while
the run computes (0.3–0.7 s that were on the critical path), and draws the figures
while the app writes the run's other files, on one process per usable CPU (forks of
itself, warm: :func:`draw_in_parallel`). A job is ``(name, keyword arguments)``: a
figure of :data:`mosd.app.figures.FIGURES` or a system's study figure
(:func:`study_figures`); :data:`FIGURES` lists them all.
"""
from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Sequence

from . import figures

#: The jobs a :class:`FigureWriter` may draw: the run's figures (:mod:`mosd.app.figures`) and a study's.
FIGURES = (*figures.FIGURES, "study_figures")

#: Nice value of the warm-up figure's thread (Linux: per thread): the run's own processes come first.
WARM_UP_NICE = 10

#: Seconds the figures wait for the warm-up figure to end (it is drawn on, beside them, past that).
WARM_UP_WAIT_S = 0.25


def _warm_up_in_background(stop) -> None:
    """:func:`mosd.app.figures._warm_up` in its own thread (see :func:`_serve`): the imports at the normal
    priority, the figure lower.

    The imports are not lowered: the figures need them, and drawing them waits on the import lock
    this thread holds; at nice 10 on a busy 2-core machine the imports were still running when the
    figures arrived (2 runs in 3 at load 3), and the figures waited for them at that priority.
    """
    import threading

    try:
        figures._load_drawing()
        if sys.platform.startswith("linux"):
            # on Linux a nice value belongs to a thread: only the warm-up yields, not the drawing
            try:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WARM_UP_NICE)
            except OSError:
                pass
        figures._warm_up(stop)
    except Exception:  # a warm-up is an optimisation: the real figures report real errors
        pass


def study_figures(study, method: str, kwargs: dict) -> list[Path]:
    """One of a system's study figure jobs (:meth:`mosd.systems.base.Study.figure_jobs`): ``study.method(**kwargs)``,
    its path or paths as a list.

    A job like the run's own figures, so that a study's figures, drawn in the run's process before, are drawn
    by the figure process beside the run's (1.4–4 s of a preset's study on the 2-core machine; issue 32).
    """
    drawn = getattr(study, method)(**kwargs)
    return [Path(p) for p in drawn] if isinstance(drawn, (list, tuple)) else [Path(drawn)]


def draw(jobs: Sequence[tuple[str, dict[str, Any]]]) -> list[Path]:
    """Draw ``(figure name, keyword arguments)`` jobs in this process, in order; the PNG paths."""
    return _flat(_draw_each(jobs))


def _draw_each(jobs: Sequence[tuple[str, dict[str, Any]]]) -> list[list[Path]]:
    """Each job's PNG paths, in order: one for a run figure, a study's for :func:`study_figures`."""
    out = []
    for name, kwargs in jobs:
        if name not in FIGURES:
            raise ValueError(f"{name!r} is not a figure; allowed: {', '.join(FIGURES)}")
        # a run figure is a function of mosd.app.figures, a study's job this module's own
        drawn = study_figures(**kwargs) if name == "study_figures" else getattr(figures, name)(**kwargs)
        out.append(drawn if isinstance(drawn, list) else [drawn])
    return out


def _flat(per_job: Sequence[Sequence]) -> list[Path]:
    return [Path(p) for drawn in per_job for p in drawn]


#: Relative drawing cost of each figure (CPU seconds, warm, best of 3, measured on the project's 2-core machine
#: at load 2: the chart's log-scale ticks are the dearest): how :func:`shares` balances the drawing processes.
FIGURE_COST = {"chart_trace": 0.30, "optimisation_history": 0.26, "pareto_pairs": 0.25, "pareto_front": 0.22,
               "residual_trace": 0.21, "study_figures": 0.8}


def shares(jobs: Sequence[tuple[str, dict[str, Any]]], drawers: int) -> list[list[int]]:
    """The job indices of each of ``drawers`` processes, balanced by :data:`FIGURE_COST` (largest first).

    Empty shares are dropped; each share keeps the jobs' order.
    """
    loads = [[0.0, []] for _ in range(max(1, min(int(drawers), len(jobs))))]
    for i in sorted(range(len(jobs)), key=lambda i: -FIGURE_COST.get(jobs[i][0], 1.0)):
        least = min(loads, key=lambda load: load[0])
        least[0] += FIGURE_COST.get(jobs[i][0], 1.0)
        least[1].append(i)
    return [sorted(indices) for _, indices in loads if indices]


def _die_with_parent(parent: int) -> bool:
    """Linux: this (forked) process is killed when ``parent`` dies; False where that cannot be arranged."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, 9, 0, 0, 0) != 0:  # PR_SET_PDEATHSIG, SIGKILL
            return False
    except (OSError, AttributeError):
        return False
    return os.getppid() == parent  # the parent may have died before the call


def draw_in_parallel(jobs: Sequence[tuple[str, dict[str, Any]]], drawers: int) -> list[Path]:
    """:func:`draw` on ``drawers`` processes: this one and ``drawers - 1`` forks of it (Linux), same files.

    The figure process has matplotlib loaded and warm: a fork starts drawing at once
    and shares those pages. Each fork draws its share (:func:`shares`) and dies with
    this process (a figure process killed by the app leaves no drawer behind to write
    a PNG later). The first error, here or in a fork, is raised once every fork has
    ended. One drawer, or no ``fork``: :func:`draw`.
    """
    parts = shares(jobs, drawers)
    if len(parts) < 2 or not sys.platform.startswith("linux"):
        return draw(jobs)
    parent, forks = os.getpid(), []
    for part in parts[1:]:
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:  # the fork: draw its share, reply on its pipe, leave without any teardown
            code = 1
            try:
                os.close(read)
                if _die_with_parent(parent):
                    try:
                        drawn = _draw_each([jobs[i] for i in part])
                        reply = {"ok": True, "paths": [[str(p) for p in paths] for paths in drawn]}
                    except Exception as exc:
                        reply = {"ok": False, "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
                    with os.fdopen(write, "wb") as out:
                        pickle.dump(reply, out)
                    code = 0
            finally:
                os._exit(code)
        os.close(write)
        forks.append((pid, read, part))
    paths: list = [None] * len(jobs)
    error = None
    try:
        for i, path in zip(parts[0], _draw_each([jobs[i] for i in parts[0]])):
            paths[i] = path
    except Exception as exc:
        error = exc
    for pid, read, part in forks:
        with os.fdopen(read, "rb") as replies:
            try:
                reply = pickle.load(replies)
            except (EOFError, pickle.UnpicklingError):
                reply = {"ok": False, "error": "a drawing process ended without drawing its figures"}
        os.waitpid(pid, 0)
        if reply["ok"]:
            for i, path in zip(part, reply["paths"]):
                paths[i] = path
        elif error is None:
            error = RuntimeError(reply["error"])
    if error is not None:
        raise error
    return _flat(paths)


def usable_cpus() -> int:
    """The CPUs this process may run on.

    :func:`mosd.optim.workers.available_cpus`'s arithmetic, not imported from there: importing ``mosd.optim``
    loads pymoo, which neither the figure process nor the check before preflight (:func:`mosd.app.spare_core`)
    needs."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def free_cpus() -> int:
    """The usable CPUs no runnable thread holds right now (negative: threads queue for them), this one's included.

    Linux: the runnable threads of the whole machine at this instant (the fourth field of
    ``/proc/loadavg``), which sees a busy machine at once where the 1-minute load average
    lags a minute behind (and counts a run's own previous minute); elsewhere that average,
    rounded up. What extra processes can use without taking time from other work: the figures
    are drawn on more than one process (:func:`_serve`), and the side processes start before
    the checks (:func:`mosd.app.spare_core`), only when it is at least one.
    """
    import math

    try:
        with open("/proc/loadavg") as fh:
            runnable = int(fh.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        try:
            runnable = math.ceil(os.getloadavg()[0]) + 1  # + this thread, which the average has not seen yet
        except (AttributeError, OSError):
            return 0
    return usable_cpus() - runnable


def _serve(drawers: int = 0) -> None:
    """Side-process main: warm up, then draw each pickled job list from stdin; pickled replies on stdout.

    ``drawers``: processes that may draw a job list (0: one per usable CPU), see :func:`draw_in_parallel`;
    no more than one plus the CPUs free (:func:`free_cpus`): on a busy machine a fork would only add
    its copying (about 15 % more CPU for the four figures) to a queue of work.
    """
    import signal

    # the app ends this process when it stops (close or kill): a Ctrl-C meant for the app must not
    # print a traceback from here first
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import threading

    requests, replies = sys.stdin.buffer, os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything a library prints must not corrupt the reply channel
    # the warm-up runs while the run computes, at a lower priority (the run's processes are on the
    # critical path, the warm-up is not); the figures themselves are drawn by this thread at the
    # normal priority, once the warm-up has finished or stopped between two figures
    stop = threading.Event()
    warm = threading.Thread(target=_warm_up_in_background, args=(stop,), name="mosd-figures-warm-up", daemon=True)
    warm.start()
    while True:
        try:
            jobs = pickle.load(requests)
        except EOFError:  # the app closed the channel (or died): nothing more to draw
            break
        stop.set()
        # a warm-up figure starved by a busy machine is not waited for: the figures are drawn here meanwhile,
        # on this process alone (a fork of a process with a second thread at work could inherit its locks)
        warm.join(WARM_UP_WAIT_S)
        try:
            # one drawer more than the free CPUs, the app's counted as free: it waits once its text files are written
            free = free_cpus() + 1
            paths = draw_in_parallel(jobs, 1 if warm.is_alive() else min(drawers or usable_cpus(), 1 + max(0, free)))
            reply = {"ok": True, "paths": [str(p) for p in paths]}
        except Exception as exc:  # reported to the app, which draws in-process instead
            reply = {"ok": False, "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
        pickle.dump(reply, replies)
        replies.flush()
    os._exit(0)  # no teardown with matplotlib loaded: the app does not wait for it


class FigureWriter:
    """Draws figures in a side process started at construction (see the module docstring).

    ``drawers``: how many processes draw a job list at once (:func:`draw_in_parallel`);
    None, one per CPU the side process may use (a sweep's job passes its share of the cores).

    :meth:`submit` sends a job list and returns at once; :meth:`result` waits for
    the PNGs. Whatever goes wrong in the side process (it could not start, it
    died, a figure raised), :meth:`result` draws the jobs in this process
    instead, so a figure is never lost to the optimisation of its drawing.
    :meth:`close` (idempotent) ends the process.
    """

    def __init__(self, drawers: int | None = None):
        package_parent = str(Path(__file__).resolve().parents[2])  # the directory holding mosd/
        self._stderr = tempfile.TemporaryFile()
        self._jobs: list[tuple[str, dict[str, Any]]] | None = None
        #: the ``drawers`` it was started with (0: one per usable CPU): a kept writer serves a job asking the same
        self.drawers = max(0, int(drawers or 0))
        #: why the last :meth:`result` drew in this process (None: the side process drew)
        self.fallback: str | None = None
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
                 "from mosd.app.plots import _serve; _serve(int(sys.argv[2]))", package_parent,
                 str(self.drawers)],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr)
        except OSError as exc:
            self._proc, self.fallback = None, f"the figure process did not start: {exc}"

    def submit(self, jobs: Sequence[tuple[str, dict[str, Any]]]) -> None:
        """Send ``(figure name, keyword arguments)`` jobs (see :data:`FIGURES`); returns at once."""
        self._jobs = [(name, dict(kwargs)) for name, kwargs in jobs]
        if self._proc is None:
            return
        try:
            payload = pickle.dumps(self._jobs)
        except Exception as exc:  # noqa: BLE001 - a job that cannot cross (a study holding an open resource): drawn here
            fallback = f"the figures could not be sent to the figure process: {type(exc).__name__}: {exc}"
            self.close(wait=False)
            self.fallback = fallback
            return
        try:
            self._proc.stdin.write(payload)
            self._proc.stdin.flush()
        except OSError as exc:
            self.fallback = f"the figure process ended: {exc}"
            self._kill()

    def result(self) -> list[Path]:
        """The PNG paths of the submitted jobs, drawn by the side process or else here."""
        jobs, self._jobs = self._jobs or [], None
        if self._proc is not None:
            try:
                reply = pickle.load(self._proc.stdout)
            except (EOFError, OSError, pickle.UnpicklingError) as exc:
                reply = {"ok": False, "error": f"the figure process ended ({exc or 'no reply'}): "
                                               f"{self._stderr_tail()}"}
            if reply.get("ok"):
                self.fallback = None
                return [Path(p) for p in reply["paths"]]
            self.fallback = reply.get("error", "no reply")
            self._kill()
        return draw(jobs)

    def alive(self) -> bool:
        """Whether the side process is running and waiting for work (no job list of this writer is pending)."""
        return self._proc is not None and self._jobs is None and self.fallback is None and self._proc.poll() is None

    def close(self, wait: bool = True) -> None:
        """End the side process (it draws nothing more); ``wait=False`` kills it at once."""
        if self._proc is None:
            return
        if not wait:
            self._kill()
        try:
            self._proc.stdin.close()  # EOF: the process leaves its loop and exits
        except OSError:
            pass
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:  # still importing matplotlib: nothing to keep
            self._kill()
        self._proc = None
        self._stderr.close()

    def _kill(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()

    def _stderr_tail(self) -> str:
        try:
            self._stderr.seek(0)
            lines = [ln.strip() for ln in self._stderr.read().decode(errors="replace").splitlines() if ln.strip()]
        except (OSError, ValueError):
            return ""
        return lines[-1] if lines else ""


# ------------------------------------------------------------------------------------
# a single run's figure process, started before the command line is checked
# ------------------------------------------------------------------------------------
_EARLY: list[FigureWriter] = []
#: a sweep job's figure process, idle, kept for this process's next job (:func:`keep`)
_KEPT: list[FigureWriter] = []


def start_early() -> None:
    """Start the figure process now, for the run this process is about to check and start.

    Called by the app before preflight: checking the command line (composition,
    components, the dry run) keeps one core busy, and the figure process imports
    matplotlib and warms up on the other instead of beside the optimiser's threads.
    The run takes it with :func:`take`; :func:`discard` ends one nobody took.
    """
    discard()
    _EARLY.append(FigureWriter())


def take(drawers: int | None = None) -> FigureWriter:
    """The figure process :func:`start_early` started (once), else one :func:`keep` kept, else a new one.

    ``drawers`` is for a kept or a new one (a sweep's job passes its share of the cores); the early one
    draws on every usable CPU (it is only started for a single run).
    """
    if _EARLY:
        return _EARLY.pop()
    wanted = max(0, int(drawers or 0))
    while _KEPT:
        writer = _KEPT.pop()
        if writer.drawers == wanted and writer.alive():
            return writer
        writer.close(wait=False)
    return FigureWriter(drawers)


def keep(writer: FigureWriter) -> bool:
    """Keep a sweep job's figure process, its drawing done, for the next job of this process; False: closed.

    A sweep's jobs in one process (the basic launcher's, a joblib worker's) then share one
    figure process: matplotlib's import and warm-up (1.0–1.4 s of CPU on the project's 2-core
    machine) are paid once per process, not once per job. One that failed or died is closed.
    The process ends when this one does (its request pipe closes), or with :func:`discard`.
    """
    if not writer.alive():
        writer.close(wait=False)
        return False
    while _KEPT:
        _KEPT.pop().close(wait=False)
    _KEPT.append(writer)
    return True


def early_pids() -> list[int]:
    """The process id of the figure process :func:`start_early` started, while no run has taken it."""
    return [writer._proc.pid for writer in _EARLY if writer._proc is not None]


def discard() -> None:
    """End the figure process :func:`start_early` started, if no run took it (an error, a sweep), and a kept one."""
    while _EARLY:
        _EARLY.pop().close(wait=False)
    while _KEPT:
        _KEPT.pop().close(wait=False)

"""Startup and the critical path of the main command: what is imported where, what is printed when.

Checked on ``sys.modules`` and on the order of the output, never on timings (the
machine is shared): ``--help`` loads none of the heavy libraries, the run's main
process loads neither MLflow (side process) nor matplotlib (figure process), the
first line of a run comes before its end, and the fast exit keeps the exit code,
the cleanup handlers and everything printed.
"""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import mosd as mosd_package

PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])
HEAVY = ("mlflow", "matplotlib", "pymoo", "numba", "scipy", "torch", "sklearn")
REDUCED = ["optimizer.pop_size=6", "optimizer.n_gen=2", "budget.n_test=3", "budget.n_train=2",
           "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false"]


def _env(tmp_path: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    env["MOSD_OUTPUTS"] = str(tmp_path / "outputs")
    return env


def _python(code: str, tmp_path: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code, *args], cwd=tmp_path, env=_env(tmp_path),
                          capture_output=True, text=True, timeout=timeout)


# what a process has loaded, printed as the last line of stdout after mosd.app.main(argv) returned
_MODULES_AFTER_MAIN = """
import json, sys
import mosd.app
try:
    code = mosd.app.main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
print()
print(json.dumps({"code": code, "loaded": sorted(m for m in %r if m in sys.modules)}))
""" % (HEAVY,)


def test_import_of_the_app_loads_no_heavy_library(tmp_path):
    probe = _python(f"import json, sys, mosd.app; print(json.dumps([m for m in {HEAVY + ('hydra',)!r} "
                    f"if m in sys.modules]))", tmp_path)
    assert probe.returncode == 0, probe.stderr
    assert json.loads(probe.stdout) == []


def test_help_loads_neither_mlflow_nor_matplotlib_nor_pymoo(tmp_path):
    probe = _python(_MODULES_AFTER_MAIN, tmp_path, "--help")
    assert probe.returncode == 0, probe.stderr
    assert "mosd" in probe.stdout and "+fault=" in probe.stdout  # Hydra's help with the app's header
    state = json.loads(probe.stdout.strip().splitlines()[-1])
    assert state == {"code": 0, "loaded": []}, state


def test_a_run_keeps_mlflow_and_matplotlib_out_of_the_main_process(tmp_path):
    # MLflow runs in the tracking side process, matplotlib in the figure process
    probe = _python(_MODULES_AFTER_MAIN, tmp_path, "+fault=offset_var", *REDUCED, timeout=300)
    assert probe.returncode == 0, probe.stderr[-3000:]
    state = json.loads(probe.stdout.strip().splitlines()[-1])
    assert state["code"] == 0 and "mlflow" not in state["loaded"] and "matplotlib" not in state["loaded"], state
    run_dir = next((tmp_path / "outputs" / "runs").iterdir())
    names = {p.name for p in run_dir.iterdir()}
    assert {"pareto.png", "chart.png", "residual.png", "history.png", "summary.json"} <= names, names
    assert not [n for n in names if n.startswith(".") and n.endswith(".png")], names  # no temporary figure
    for png in ("pareto.png", "chart.png", "residual.png", "history.png"):
        assert (run_dir / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", png
    # the summary's first line is printed once, at the start, and the summary follows it
    lines = probe.stdout.splitlines()
    assert lines[0].startswith("mosd  fault=offset_var  detector=") and "optimizer=mopso (6 × 2)" in lines[0]
    assert sum(line.startswith("mosd  fault=") for line in lines) == 1
    assert lines[1].startswith("chosen") and any(line.startswith("wall time") for line in lines)


# the number of times a command builds the components, printed as the last line of stdout
_COUNTING_BUILDS = """
import json, sys
import mosd.app, mosd.app.build as build_module, mosd.app.preflight as preflight_module, mosd.app.run as run_module
built = []
real = build_module.build
def counting(cfg):
    built.append(1)
    return real(cfg)
preflight_module.build = run_module.build = counting
code = mosd.app.main(sys.argv[1:])
print()
print(json.dumps({"code": code, "builds": len(built)}))
"""


@pytest.mark.parametrize("sweep", [False, True])
def test_the_components_are_built_once_per_job(tmp_path, sweep):
    """Preflight builds each job's components; the job run in the same process takes them (no second build)."""
    args = ["-m", "+fault=offset,offset_var"] if sweep else ["+fault=offset_var"]
    probe = _python(_COUNTING_BUILDS, tmp_path, *args, *REDUCED, "tracking=none", timeout=300)
    assert probe.returncode == 0, probe.stderr[-3000:]
    state = json.loads(probe.stdout.strip().splitlines()[-1])
    assert state == {"code": 0, "builds": 2 if sweep else 1}, state


def test_the_first_line_comes_before_the_end_of_the_run_off_a_terminal(tmp_path):
    # a run far longer than the test waits for: its first line must arrive while it is still running
    args = ["+fault=offset_var", "optimizer.pop_size=6", "optimizer.n_gen=100000", "budget.n_test=2",
            "budget.n_train=2", "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false", "tracking=none"]
    proc = subprocess.Popen([sys.executable, "-m", "mosd", *args], cwd=tmp_path, env=_env(tmp_path),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 120)
        assert ready, "nothing printed within 120 s"
        first = proc.stdout.readline()
        assert proc.poll() is None, proc.stderr.read()[-3000:]
        assert first.startswith("mosd  fault=offset_var  detector=ss_dewma"), first
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err[-3000:]
    assert len(err.strip().splitlines()) == 1 and "stopped by SIGTERM" in err, err[-3000:]
    summary = json.loads(next((tmp_path / "outputs" / "runs").iterdir()).joinpath("summary.json").read_text())
    assert summary["status"] == "killed"


def test_exit_now_keeps_the_code_the_cleanup_handlers_and_the_buffered_output(tmp_path):
    code = ("import atexit, sys, mosd.app\n"
            "atexit.register(lambda: print('cleanup ran'))\n"
            "sys.stdout.write('buffered, no newline; ')\n"
            "sys.stderr.write('err too')\n"
            "mosd.app.exit_now(3)\n"
            "print('not reached')\n")
    done = _python(code, tmp_path)
    assert done.returncode == 3
    assert done.stdout == "buffered, no newline; cleanup ran\n" and done.stderr == "err too"


# ---------------------------------------------------------------------------------------
# figures: the side process, its fallback, no half-written PNG
# ---------------------------------------------------------------------------------------
def _jobs(folder: Path):
    rng = np.random.default_rng(1)
    t = np.arange(200) * 0.01
    mask = t >= 1.0
    F = np.column_stack([np.linspace(0, 0.2, 6), np.linspace(0.2, 0, 6)])
    return [("pareto_front", dict(path=folder / "pareto.png", F=F, chosen=2, title="t")),
            ("chart_trace", dict(path=folder / "chart.png", t=t, statistic=rng.random(200) + 3 * mask,
                                 ucl=np.full(200, 2.0), fault_mask=mask, title="t"))]


def test_figure_writer_draws_in_its_process(tmp_path):
    from mosd.app.plots import FigureWriter

    writer = FigureWriter()
    try:
        writer.submit(_jobs(tmp_path))
        paths = writer.result()
    finally:
        writer.close()
    assert paths == [tmp_path / "pareto.png", tmp_path / "chart.png"] and writer.fallback is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chart.png", "pareto.png"]
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in paths)


def test_figure_writer_draws_here_when_its_process_is_gone(tmp_path):
    from mosd.app.plots import FigureWriter

    writer = FigureWriter()
    writer._proc.kill()
    writer._proc.wait()
    try:
        writer.submit(_jobs(tmp_path))
        paths = writer.result()
    finally:
        writer.close()
    assert writer.fallback and "ended" in writer.fallback
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in paths)


def test_figure_writer_reports_a_bad_job_and_draws_it_here(tmp_path):
    from mosd.app.plots import FigureWriter

    writer = FigureWriter()
    try:
        writer.submit([("no_such_figure", {"path": tmp_path / "x.png"})])
        with pytest.raises(ValueError, match="no_such_figure.*allowed: pareto_front"):
            writer.result()
        assert "no_such_figure" in writer.fallback
    finally:
        writer.close()


def test_a_figure_that_fails_while_saving_leaves_no_file(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    from mosd.app import figures as plots

    def broken(self, *args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        plots.pareto_front(tmp_path / "pareto.png", np.array([[0.1, 0.2], [0.2, 0.1]]))
    assert list(tmp_path.iterdir()) == []


def test_close_ends_the_figure_process_promptly(tmp_path):
    from mosd.app.plots import FigureWriter

    writer = FigureWriter()
    proc = writer._proc
    t0 = time.monotonic()
    writer.close(wait=False)  # a stopped run: the process may still be importing matplotlib
    assert proc.poll() is not None and time.monotonic() - t0 < 5


# ---------------------------------------------------------------------------------------
# a terminal sees a line at once while the command line is checked; an error stays one line
# ---------------------------------------------------------------------------------------
def _on_a_terminal(tmp_path: Path, args: list[str], timeout: float = 120) -> tuple[int, str, str]:
    """Run ``python -m mosd ARGS`` with stderr on a pseudo-terminal; (exit code, stdout, terminal bytes)."""
    import pty

    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "mosd", *args], cwd=tmp_path, env=_env(tmp_path),
                            stdout=subprocess.PIPE, stderr=slave, stdin=subprocess.DEVNULL)
    os.close(slave)
    seen = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # the terminal's other side closed: the process has ended
                break
            if not chunk:
                break
            seen += chunk
        elif proc.poll() is not None:
            break
    os.close(master)
    out = proc.communicate(timeout=timeout)[0].decode()
    return proc.returncode, out, seen.decode(errors="replace")


def test_a_terminal_sees_the_check_at_once_and_an_error_is_still_one_line(tmp_path):
    from mosd.app import CHECKING

    code, out, seen = _on_a_terminal(tmp_path, ["+fault=offset_var", "detector.lam=1.5"])
    assert code == 2 and out == ""
    assert seen.startswith(CHECKING + "\r\x1b[K"), seen  # shown first, erased before the error
    rest = seen[len(CHECKING) + 4:].replace("\r\n", "\n").strip().splitlines()
    assert len(rest) == 1 and rest[0].startswith("mosd: error: detector.lam=1.5 is out of range"), seen
    assert not (tmp_path / "outputs").exists()


def test_help_on_a_terminal_shows_no_check_line(tmp_path):
    from mosd.app import CHECKING

    code, out, seen = _on_a_terminal(tmp_path, ["--help"])
    assert code == 0 and "+fault=" in out and CHECKING not in seen

"""Issue 32, the fixed part of a run: the figures drawn on several processes, the figure process started
before the command line is checked, and neither leaving a process or a half-written PNG behind."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mosd.app import plots

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork and /proc: Linux")


def _jobs(folder: Path, points: int = 300):
    rng = np.random.default_rng(3)
    t = np.arange(points) * 0.01
    mask = t >= t[points // 2]
    F = np.column_stack([np.linspace(0, 0.2, 6), np.linspace(0.2, 0, 6)])
    records = [{"generation": g, "n_eval": 10 * g, "archive_size": g, "hypervolume": 1.0, "best_accuracy": 0.9}
               for g in (1, 2, 3)]
    return [("pareto_front", dict(path=folder / "pareto.png", F=F, chosen=2, title="t")),
            ("chart_trace", dict(path=folder / "chart.png", t=t, statistic=rng.random(points) + 60 * mask,
                                 ucl=np.full(points, 2.0), fault_mask=mask, title="t")),
            ("residual_trace", dict(path=folder / "residual.png", residual=rng.normal(size=points),
                                    fault_mask=mask, dt=0.01, sigma=1.0, channel_name="y")),
            ("optimisation_history", dict(path=folder / "history.png", records=records, title="t"))]


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_shares_balance_the_figures_and_keep_each_once():
    jobs = _jobs(Path("x"))
    two = plots.shares(jobs, 2)
    assert sorted(i for part in two for i in part) == [0, 1, 2, 3]
    # the chart (log-scale ticks) is the dearest: it is not drawn by the process that draws the history
    assert {1, 2} in [set(part) for part in two] and {0, 3} in [set(part) for part in two]
    assert plots.shares(jobs, 1) == [[0, 1, 2, 3]]
    assert plots.shares(jobs, 16) == [[1], [3], [0], [2]]  # at most one process per figure
    assert plots.shares(jobs[:1], 0) == [[0]]


def test_figures_drawn_on_two_processes_are_the_files_one_process_draws(tmp_path):
    serial, parallel = tmp_path / "serial", tmp_path / "parallel"
    serial.mkdir(), parallel.mkdir()
    before = set(_children(os.getpid()))  # an xdist worker may hold other tests' pools (loky's workers)
    paths = plots.draw_in_parallel(_jobs(parallel), 2)
    assert paths == [parallel / n for n in ("pareto.png", "chart.png", "residual.png", "history.png")]
    plots.draw(_jobs(serial))
    for path in paths:
        assert path.read_bytes() == (serial / path.name).read_bytes(), path.name
    assert sorted(p.name for p in parallel.iterdir()) == sorted(p.name for p in serial.iterdir())
    assert set(_children(os.getpid())) - before == set()  # every fork waited for


def test_an_error_in_a_fork_is_raised_after_every_fork_ended(tmp_path):
    jobs = _jobs(tmp_path)
    jobs[3] = ("optimisation_history", dict(path=tmp_path / "no_such_folder" / "history.png", records=[]))
    # the history goes to a fork (shares: chart+residual here, pareto+history there)
    before = set(_children(os.getpid()))
    with pytest.raises(RuntimeError, match="history|IndexError|FileNotFoundError|No such file"):
        plots.draw_in_parallel(jobs, 2)
    assert set(_children(os.getpid())) - before == set()
    assert {"chart.png", "residual.png", "pareto.png"} == {p.name for p in tmp_path.iterdir() if p.is_file()}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary PNG left


DRAWING = """
import sys
from pathlib import Path
import numpy as np
from mosd.app import plots
folder, points = Path(sys.argv[1]), 400_000
t = np.arange(points) * 0.01
mask = t >= t[points // 2]
statistic = np.random.default_rng(0).random(points) + 60 * mask
jobs = [("chart_trace", dict(path=folder / f"chart{i}.png", t=t, statistic=statistic, ucl=np.full(points, 2.0),
                             fault_mask=mask)) for i in range(4)]
plots.draw_in_parallel(jobs, 4)
"""


def test_a_killed_drawing_process_leaves_no_fork_behind(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(Path(plots.__file__).resolve().parents[2]))
    proc = subprocess.Popen([sys.executable, "-c", DRAWING, str(tmp_path)], env=env)
    try:
        deadline = time.monotonic() + 90
        while len(_children(proc.pid)) < 3 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.01)
        forks = _children(proc.pid)
        assert len(forks) == 3, "the drawing process did not fork its drawers"
        proc.kill()  # as the app kills its figure process
        proc.wait()
        deadline = time.monotonic() + 10
        while any(_alive(pid) for pid in forks) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(_alive(pid) for pid in forks)  # each fork died with it: no PNG written later
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


EARLY = """
import sys
import mosd.app
from mosd.app import channel, main, plots
mosd.app.spare_core = lambda: True  # whatever the machine's load: this test is about the processes
started = {}
def counting(module, key):
    real = module.start_early
    def start():
        real()
        started[key] = module._EARLY[-1]._proc
    module.start_early = start
counting(plots, "figures")
counting(channel, "tracking")
code = main(sys.argv[1:])
print("CODE", code, "LEFT", len(plots._EARLY) + len(channel._EARLY),
      *(f"{key}={proc.poll()}" for key, proc in sorted(started.items())))
"""


def _early(tmp_path: Path, *args: str) -> tuple[list[str], str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env.update(PYTHONPATH=str(Path(plots.__file__).resolve().parents[2]), MOSD_OUTPUTS=str(tmp_path / "out"))
    done = subprocess.run([sys.executable, "-c", EARLY, "+fault=offset_var", *args], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip().splitlines()[-1].split(), done.stderr


def test_the_early_side_processes_end_when_the_command_is_refused(tmp_path):
    line, stderr = _early(tmp_path, "optimizer=no_such")
    # both started before preflight, both killed (SIGKILL: -9) and waited for; nothing written
    assert line == ["CODE", "2", "LEFT", "0", "figures=-9", "tracking=-9"], line
    assert "optimizer" in stderr and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_run_takes_the_early_side_processes(tmp_path):
    line, _ = _early(tmp_path, "debug=tiny")
    # the run used both: the tracking process ended the MLflow run and left by itself (0), the figure
    # process drew the PNGs and was closed (0)
    assert line == ["CODE", "0", "LEFT", "0", "figures=0", "tracking=0"], line
    run_dir = next((tmp_path / "out" / "runs").iterdir())
    assert {"pareto.png", "chart.png", "history.png", "summary.json"} <= {p.name for p in run_dir.iterdir()}
    line, _ = _early(tmp_path, "debug=tiny", "tracking=none")
    assert line == ["CODE", "0", "LEFT", "0", "figures=0"], line  # tracking off: no tracking process started


def test_the_side_processes_start_early_only_with_a_core_to_spare(monkeypatch):
    import builtins
    import io

    import mosd.app

    state = {"runnable": 1}
    real_open = builtins.open

    def fake_open(path, *args, **kwargs):
        if path == "/proc/loadavg":
            return io.StringIO(f"7.00 6.00 5.00 {state['runnable']}/900 12345\n")
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", fake_open)
    monkeypatch.setattr(plots, "usable_cpus", lambda: 2)
    # a minute of load 7 behind, but only this process runnable now: the other CPU is free
    assert plots.free_cpus() == 1 and mosd.app.spare_core()
    state["runnable"] = 3  # one more thread than CPUs: nothing free
    assert plots.free_cpus() == -1 and not mosd.app.spare_core()
    state["runnable"] = 1
    monkeypatch.setattr(plots, "usable_cpus", lambda: 1)  # one CPU: the checks take it
    assert not mosd.app.spare_core()


def test_a_studys_figures_are_a_figure_job_drawn_beside_the_runs_with_the_same_files(tmp_path):
    """The app hands a study's figures to its figure process (plots.study_figures) instead of drawing them in the
    run's process: drawn beside the run's figures by a second drawer, they are the files write_figures draws."""
    from types import SimpleNamespace

    from mosd.systems import cli, paper000

    experiment = cli.preset("paper000", ["seed=2", "budget.n_calibration=2", "budget.n_train=2",
                                         "budget.n_test=4"]).experiment
    detector = experiment.detector.with_params(**paper000.PAPER_PRESETS["SS-DEWMA"]["offset_var"])
    study = paper000.Study(n_runs=4)
    metrics, data = study.measure(experiment, SimpleNamespace(detector=detector, params={}))
    assert metrics["ss_dewma_far"] == metrics["far"]
    serial, parallel = tmp_path / "serial", tmp_path / "parallel"
    serial.mkdir(), parallel.mkdir()
    expected = study.write_figures(data, serial)
    jobs = [*_jobs(parallel), *[("study_figures", {"study": study, "method": method, "kwargs": kwargs})
                                for method, kwargs in study.figure_jobs(data, parallel)]]
    assert len(jobs) == 5  # paper 000's one figure: the default, write_figures whole
    assert [4] in plots.shares(jobs, 2)  # the study alone on one drawer
    paths = plots.draw_in_parallel(jobs, 2)
    assert paths[:4] == [parallel / n for n in ("pareto.png", "chart.png", "residual.png", "history.png")]
    assert paths[4:] == [parallel / p.name for p in expected] and expected
    for path in paths[4:]:
        assert path.read_bytes() == (serial / path.name).read_bytes(), path.name
    assert plots.draw(jobs[4:]) == paths[4:]  # one process: the same paths, flattened


def test_a_job_that_cannot_reach_the_figure_process_is_drawn_in_the_run(tmp_path):
    """A figure job that does not pickle (a study holding a local object) is drawn in the run's process, and the
    writer says why; the run's own figures are still drawn."""

    class LocalStudy:  # a local class: pickle cannot name it
        def write_figures(self, data, out_dir):
            path = Path(out_dir) / "local.txt"
            path.write_text(str(data["value"]))
            return [path]

    writer = plots.FigureWriter()
    try:
        writer.submit([*_jobs(tmp_path)[:1], ("study_figures", {
            "study": LocalStudy(), "method": "write_figures", "kwargs": {"data": {"value": 3}, "out_dir": tmp_path}})])
        paths = writer.result()
    finally:
        writer.close()
    assert paths == [tmp_path / "pareto.png", tmp_path / "local.txt"]
    assert (tmp_path / "local.txt").read_text() == "3" and (tmp_path / "pareto.png").stat().st_size > 1000
    assert "could not be sent to the figure process" in writer.fallback and not writer.alive()

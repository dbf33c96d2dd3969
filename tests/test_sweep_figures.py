"""A sweep's jobs in one process share one figure process (issue 32, "the fixed part" of a run).

Each job used to start its own figure process, which imported matplotlib and warmed up again
(1.0-1.4 s of CPU per job on the project's 2-core machine); a job now keeps its figure process,
idle, for the next job of the same process (:func:`mosd.app.plots.keep`).
"""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import mosd as mosd_package
from mosd.app import plots

PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])


def _residual_job(path: Path) -> list[tuple[str, dict]]:
    mask = np.zeros(200, bool)
    mask[120:] = True
    return [("residual_trace", dict(path=path, residual=np.sin(np.arange(200) / 9.0), fault_mask=mask, dt=0.01))]


def _draw(writer: plots.FigureWriter, path: Path) -> list[Path]:
    writer.submit(_residual_job(path))
    return writer.result()


def test_a_kept_figure_process_draws_the_next_jobs_figures(tmp_path):
    writer = plots.take(drawers=1)
    try:
        first = _draw(writer, tmp_path / "first.png")
        assert writer.fallback is None and first == [tmp_path / "first.png"]
        pid = writer._proc.pid
        assert plots.keep(writer)
        again = plots.take(drawers=1)
        assert again is writer and again._proc.pid == pid  # the same process, matplotlib already loaded
        second = _draw(again, tmp_path / "second.png")
        assert again.fallback is None and second == [tmp_path / "second.png"]
        assert (tmp_path / "second.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        # a job asking another share of the cores gets a process of its own; the kept one is ended
        assert plots.keep(again)
        other = plots.take(drawers=2)
        try:
            assert other is not again and again._proc is None
        finally:
            other.close()
    finally:
        writer.close(wait=False)
        plots.discard()


def test_a_dead_or_failed_figure_process_is_not_kept(tmp_path):
    writer = plots.take(drawers=1)
    try:
        _draw(writer, tmp_path / "a.png")
        writer._proc.kill()
        writer._proc.wait()
        assert not plots.keep(writer)  # closed, not kept
        fresh = plots.take(drawers=1)
        try:
            assert fresh is not writer
            assert _draw(fresh, tmp_path / "b.png") == [tmp_path / "b.png"] and fresh.fallback is None
        finally:
            fresh.close()
        pending = plots.take(drawers=1)
        pending.submit(_residual_job(tmp_path / "c.png"))  # its figures not collected: not idle, not kept
        assert not plots.keep(pending)
    finally:
        plots.discard()


@pytest.mark.slow
def test_a_sweep_in_one_process_starts_one_figure_process_for_all_its_jobs(tmp_path):
    script = textwrap.dedent(f"""
        import json, sys
        from mosd.app import plots, main

        started = []
        original = plots.FigureWriter.__init__

        def counted(self, *args, **kwargs):
            original(self, *args, **kwargs)
            started.append(self._proc.pid)

        plots.FigureWriter.__init__ = counted
        code = main(["-m", "+fault=offset,variance", "seed=1,2", "tracking=none", "progress=false",
                     "optimizer.pop_size=10", "optimizer.n_gen=3", "budget.n_test=5", "budget.n_train=3",
                     "budget.n_calibration=3", "optimizer.n_jobs=1"])
        print(json.dumps({{"code": code, "started": len(started)}}))
    """)
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    found = __import__("json").loads(done.stdout.strip().splitlines()[-1])
    assert found == {"code": 0, "started": 1}, done.stdout[-2000:]
    jobs = sorted((tmp_path / "outputs" / "multirun").glob("*/*"))
    jobs = [j for j in jobs if j.is_dir() and j.name.isdigit()]
    assert len(jobs) == 4
    for job in jobs:  # every job's figures, all drawn by the one process
        runs = [p for p in job.rglob("summary.json")]
        assert runs, f"no run in {job}"
        assert {"chart.png", "residual.png", "history.png", "pareto.png"} <= {p.name for p in runs[0].parent.iterdir()}

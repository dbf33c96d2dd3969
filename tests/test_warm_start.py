"""Issue 32, the fixed part of a warm run: what the main command imports that it does not need.

The run's test stream (``test_stream.parquet``) is written with pyarrow alone, without importing pandas
(0.65–1.1 s of the files phase). The file must read back in pandas (``mosd monitor``) exactly as the
pandas writer's did: same columns, dtypes, index and ``attrs``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

import mosd as mosd_package
from mosd.app.deploy import REFERENCE_ATTR, STREAM_FILE, Deployable, _stream, save_for_run

PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])


def _inputs(rows: int = 243):
    # an odd row count (Arrow packs the alarm column into bits) and a strided column (a view of a 2-D array)
    rng = np.random.default_rng(7)
    points = np.repeat(np.arange(rows // 4 + 1), 4)[:rows]   # 0 on the first rows: off the points
    columns = {"y_x_p": rng.normal(size=rows), "y_theta": rng.normal(size=(rows, 2))[:, 1], "u_i_q": rng.normal(size=rows)}
    decision = rng.integers(0, 2, size=points.max())
    return points, columns, SimpleNamespace(t=np.arange(rows) * 0.01), decision


def _old_writer(points, columns, outputs, decision, path: Path) -> None:
    """The pandas writer this replaces (mosd/app/deploy.py before issue 32's warm-start pass)."""
    rows = len(points)
    at = np.flatnonzero(points > 0)
    per_row = np.zeros(rows, np.int64)
    per_row[at] = decision[points[at] - 1]
    frame = pd.DataFrame({"t": np.asarray(outputs.t, float), **{k: np.asarray(v, float) for k, v in columns.items()}})
    frame["decision"] = per_row
    frame["alarm"] = per_row > 0
    frame.attrs[REFERENCE_ATTR] = ["t", "decision", "alarm"]
    frame.to_parquet(path, index=False)


def test_the_test_stream_reads_back_in_pandas_as_the_pandas_writer_wrote_it(tmp_path):
    inputs = _inputs()
    (tmp_path / "old").mkdir()
    _old_writer(*inputs, tmp_path / "old" / STREAM_FILE)
    save_for_run(None, None, tmp_path, Deployable(None, "no model here", None, _stream(*inputs)))
    old = pd.read_parquet(tmp_path / "old" / STREAM_FILE)
    new = pd.read_parquet(tmp_path / STREAM_FILE)
    pd.testing.assert_frame_equal(new, old, check_exact=True)
    pd.testing.assert_index_equal(new.columns, old.columns, exact=True)
    assert list(new.columns) == ["t", "y_x_p", "y_theta", "u_i_q", "decision", "alarm"]
    assert new.attrs == old.attrs == {REFERENCE_ATTR: ["t", "decision", "alarm"]}
    assert new["decision"].dtype == np.int64 and new["alarm"].dtype == bool
    # what the app scores in-process is what the file holds
    assert np.array_equal(_stream(*inputs)["decision"], new["decision"].to_numpy())


def test_the_main_command_imports_no_pandas(tmp_path):
    # the whole run in one interpreter (figures in their side process, as always): pandas used to be
    # imported in the files phase only to write the test stream
    # nor PyWavelets (denoise=none) nor asyncio (no Dask scheduler named), imported at module level before
    code = ("import sys; from mosd.app import main; "
            "code = main(['+fault=offset_var', 'optimizer=mopso', 'tracking=none', 'debug=tiny']); "
            "print('RESULT', code, *(name in sys.modules for name in ('pandas', 'pywt', 'asyncio')))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env.update(PYTHONPATH=PACKAGE_PARENT, MOSD_OUTPUTS=str(tmp_path / "out"))
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.splitlines()[-1] == "RESULT 0 False False False", done.stdout[-2000:]
    run_dir = next((tmp_path / "out" / "runs").glob("*"))
    assert json.loads((run_dir / "summary.json").read_text())["deployment"]["test_stream"] == STREAM_FILE
    stream = pd.read_parquet(run_dir / STREAM_FILE)
    assert stream.attrs == {REFERENCE_ATTR: ["t", "decision", "alarm"]}
    assert stream["decision"].dtype == np.int64 and stream["alarm"].dtype == bool
    assert len(stream) > 0 and np.array_equal(stream["alarm"].to_numpy(), stream["decision"].to_numpy() > 0)


def test_the_figure_process_imports_matplotlib_before_lowering_its_priority():
    # the figures wait on the import lock of the warm-up thread: at nice 10 on a busy machine they waited
    # for matplotlib's import at that priority; only the warm-up figure is lowered now
    code = ("import os, sys, threading\n"
            "seen = []\n"
            "os.setpriority = lambda which, who, nice: seen.append(('matplotlib.figure' in sys.modules, nice))\n"
            "from mosd.app import plots\n"
            "plots._warm_up_in_background(threading.Event())\n"
            "print(seen)\n")
    done = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=PACKAGE_PARENT),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "[(True, 10)]"


def test_the_warm_up_draws_one_small_figure_not_each_kind(monkeypatch):
    # each kind drawn once cost 1.1-1.7 s of CPU for 0.1-0.3 s saved on the real figures
    from mosd.app import figures as plots

    def refuse(*args, **kwargs):
        raise AssertionError("the warm-up drew a run's figure")

    for name in plots.FIGURES:
        monkeypatch.setattr(plots, name, refuse)
    saved = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: saved.append(path))
    plots._warm_up()
    assert saved == []   # into memory: no file, not even a temporary one

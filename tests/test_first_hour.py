"""A new user's first hour (issue 31): a table preset that just works, a search box checked whole before
any work, outputs a person can read (names, summary, report, figures, log), the TE files as CSV.

The tables are written by the tests (3, 8 and 60 tags: a latent structure, labelled faults that move
one tag); the runs are the real command line in a subprocess, with small budgets.
"""
from __future__ import annotations

import csv
import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from test_app import mosd


def write_table(path: Path, n_tags: int, n_rows: int = 800, seed: int = 0, extra: dict | None = None) -> Path:
    """Correlated tags and a ``fault`` column: four labelled stretches in the last half that shift one tag."""
    rng = np.random.default_rng(seed)
    latent = rng.standard_normal((n_rows, 2))
    tags = latent @ rng.standard_normal((2, n_tags)) + 0.3 * rng.standard_normal((n_rows, n_tags))
    fault = np.zeros(n_rows, int)
    for start, label in ((450, 1), (560, 2), (650, 1), (720, 2)):
        fault[start:start + 40] = label
        tags[start:start + 40, label % n_tags] += 3.0
    frame = pd.DataFrame(tags, columns=[f"tag{i}" for i in range(n_tags)])
    frame.insert(0, "fault", fault)
    for name, value in (extra or {}).items():
        frame[name] = value
    frame.to_csv(path, index=False)
    return path


SMALL = ["optimizer.pop_size=4", "optimizer.n_gen=2", "optimizer.n_jobs=1", "progress=false"]


# -- 1. +experiment=table ---------------------------------------------------------------------------
@pytest.mark.parametrize("n_tags", [3, 8, 60])
def test_the_table_preset_runs_on_a_table_of_any_width(tmp_path, n_tags):
    write_table(tmp_path / "plant.csv", n_tags)
    out = mosd(["+experiment=table", "data.path=plant.csv", "data.label_column=fault", "tracking=none", *SMALL],
               cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    summary = json.loads(next((tmp_path / "outputs" / "runs").glob("*/summary.json")).read_text())
    assert summary["status"] == "finished"
    # the component count stayed inside what the data take: tags less one
    assert 1 <= summary["params"]["n_components"] <= n_tags - 1


@pytest.mark.slow  # MLflow's logging: 30-50 s on a busy machine
def test_the_table_preset_on_8_tags_names_the_run_and_writes_readable_files(tmp_path):
    # a constant tag: dropped with one warning, not two
    write_table(tmp_path / "plant.csv", 8, extra={"flat": 1.0})
    out = mosd(["+experiment=table", "data.path=plant.csv", "data.label_column=fault", *SMALL], cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stderr.count("constant over the calibration rows") == 1, out.stderr
    run_dir = next((tmp_path / "outputs" / "runs").iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    # recorded data: no plant, noise or fault of the simulated defaults
    assert summary["labels"]["data"] == "table" and not {"plant", "noise", "fault"} & set(summary["labels"])
    assert summary["params"]["n_components"] <= 7
    # the log file holds the run's result
    log = (run_dir / "mosd.log").read_text()
    assert "chosen" in log and "FAR" in log
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'outputs' / 'mlflow.db'}")
    (run,) = client.search_runs([client.get_experiment_by_name("mosd").experiment_id])
    assert run.info.run_name == "table:plant-pca-mopso"
    assert "mosd.plant" not in run.data.tags and run.data.tags["mosd.data"] == "table"
    # the summary names the runs table in the UI
    assert any(line.startswith("ui ") and "workflowType=machine_learning" in line for line in out.stdout.splitlines())


# -- 1. preflight: the whole search box -------------------------------------------------------------
def _refused(argv, cwd, capsys):
    from mosd.app import main

    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "Traceback" not in err, err
    assert not (cwd / "outputs" / "runs").exists()
    return err


def test_preflight_refuses_a_bound_the_data_cannot_take_before_any_work(tmp_path, capsys, monkeypatch):
    write_table(tmp_path / "plant.csv", 8)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MOSD_OUTPUTS", str(tmp_path / "outputs"))
    err = _refused(["+experiment=table", f"data.path={tmp_path / 'plant.csv'}", "data.label_column=fault",
                    "+detector.bounds.n_components=[1,20]", "tracking=none"], tmp_path, capsys)
    # the first design of the box the 8 tags cannot take: the default (9) or the high end (20)
    assert err.startswith(("mosd: error: detector.bounds.n_components=[1, 20] reaches n_components=9,",
                           "mosd: error: detector.bounds.n_components=[1, 20] reaches n_components=20,")), err
    assert "allowed: integers in [1, 7]" in err
    # the default range (no bounds) is fitted to the data instead: accepted
    from mosd.app.preflight import preflight

    checked = preflight(["+experiment=table", f"data.path={tmp_path / 'plant.csv'}", "data.label_column=fault",
                         "tracking=none"])
    (setup,) = [s for same in checked._setups.values() for s in same]
    assert setup.experiment.detector.tunable["n_components"].high == 7
    # a table without the measured-signals pipeline: one line naming what works
    err = _refused(["data=table", f"data.path={tmp_path / 'plant.csv'}", "data.label_column=fault",
                    "tracking=none"], tmp_path, capsys)
    assert "without a plant model" in err and "estimator=measured" in err and "+experiment=table" in err


def test_preflight_checks_the_box_of_a_simulated_system_too(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MOSD_OUTPUTS", str(tmp_path / "outputs"))
    # the mould oscillator's three residual channels take at most 2 components
    err = _refused(["+fault=offset_var", "detector=pca", "monitor=signals", "+detector.bounds.n_components=[1,5]",
                    "tracking=none", "budget.n_test=2"], tmp_path, capsys)
    assert "detector.bounds.n_components=[1, 5]" in err and "allowed: integers in [1, 2]" in err


# -- 4. the summary ----------------------------------------------------------------------------------
def test_the_summary_advises_widening_only_where_the_parameter_can_go_further():
    from mosd.app.summary import bound_notes
    from mosd.detectors.mean_variance import SSDEWMA
    from mosd.detectors.pca import PCADetector

    pca = SimpleNamespace(experiment=SimpleNamespace(detector=PCADetector()), bounds={})
    (note,) = bound_notes({"n_components": 4, "alpha": 0.01, "lam": 0.5, "persistence": 1}, pca)
    assert note.startswith("persistence = 1 in [1, 10]") and "widen" not in note and "smallest" in note
    chart = SimpleNamespace(experiment=SimpleNamespace(detector=SSDEWMA()), bounds={"K": (0.0, 5.0)})
    (note,) = bound_notes({"lam": 0.4, "K": 5.0}, chart)
    assert "widen detector.bounds.K" in note


def test_a_study_of_a_hundred_metrics_prints_grouped_short_lines():
    from mosd.app.summary import study_lines

    study = {f"{d}_fdr_{s}_idv{f}": 0.5 + f / 100 for d in ("lit", "tuned") for s in ("t2", "spe", "combined")
             for f in range(1, 19)}
    study.update({"lit_far_combined": 0.06, "tuned_far_combined": 0.01})
    lines = study_lines("Study", study, shown=None)
    assert len(study) == 110 and max(map(len, lines)) <= 112
    assert lines[0] == "study     Study: 110 metrics"
    assert any(line.strip().startswith("lit_fdr_t2: idv1 0.51, idv2 0.52") for line in lines)
    assert sum("lit_far_combined 0.06" in line for line in lines) == 1
    # wrapped between metrics: no line starts with a value cut off from its name
    assert all(line.split()[0].startswith(("idv", "lit", "tuned")) for line in lines[1:])


def test_a_long_study_is_one_line_on_the_screen():
    """issue 51: the TE study's 384 metrics took about 80 lines of the summary."""
    from mosd.app.summary import SHOWN_STUDY_METRICS, study_lines

    long = {f"m{i}": float(i) for i in range(SHOWN_STUDY_METRICS + 1)}
    assert study_lines("Study", long) == [f"study     Study: {len(long)} metrics, in summary.json (\"study\") and "
                                          "the MLflow run (python -m mosd report --metrics study)"]
    short = dict(list(long.items())[:3])
    assert study_lines("Study", short)[0] == "study     Study: 3 metrics"


def test_the_test_line_says_what_was_scored_and_no_interval_of_one_run():
    from types import SimpleNamespace

    from mosd.app.summary import _test_runs

    recorded, simulated = SimpleNamespace(experiment=SimpleNamespace(data=object())), SimpleNamespace(
        experiment=SimpleNamespace())
    assert _test_runs(recorded, 1) == "1 run of the recorded data's test split (one run: no interval)"
    assert _test_runs(simulated, 100) == "100 fresh replications, mean ± 95 % CI half-width"


# -- 4. mosd report ----------------------------------------------------------------------------------
@pytest.fixture
def three_systems(tmp_path):
    from mosd.app import mlflow_client
    from mosd.app.settings import TrackingSettings

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    store = mlflow_client.MlflowStore(TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd"))

    def job(tags, params, far):
        run_id = store.create_run("r", {"mosd.role": "job", "mosd.detector": "pca", "mosd.optimizer": "mopso",
                                        "mosd.params": "alpha", "mosd.online": "true", **tags})
        store.log(run_id, {"seed": "0", **params}, [(k, v, 0) for k, v in
                                                     {"far": far, "mdr": 0.1, "accuracy": 0.9 - far, "alpha": 0.01,
                                                      "n_test": 1.0}.items()])
        store.end(run_id)

    table = {"data.errors": "nan", "data.fill": "hold", "data.path": "plant.csv", "data.tags": "all"}
    job({"mosd.data": "tep"}, {"data.variables": "literature"}, 0.02)
    job({"mosd.data": "table"}, table, 0.03)
    job({"mosd.data": "table"}, {**table, "data.path": "other.csv"}, 0.04)
    job({"mosd.fault": "offset", "mosd.plant": "mould_oscillator", "mosd.detector": "ss_dewma"}, {}, 0.05)
    return uri


def test_the_report_groups_runs_by_system_and_drops_empty_columns(three_systems):
    from mosd.app import report

    rows = report.collect(three_systems)
    assert [r["system"] for r in rows] == ["data=table", "data=table", "data=tep", "mould_oscillator"]
    text = report.to_markdown(rows)
    sections = text.split("### ")[1:]
    assert [s.splitlines()[0] for s in sections] == ["data=table (2 runs)", "data=tep (1 run)",
                                                     "mould_oscillator (1 run)"]
    for section in sections:
        table = [line for line in section.splitlines() if line.startswith("|")]
        header = [c.strip() for c in table[0].strip("|").split("|")]
        cells = [[c.strip() for c in line.strip("|").split("|")] for line in table[2:]]
        for i, name in enumerate(header[4:], start=4):  # beyond the identity columns: none empty on every row
            assert any(row[i] != "–" for row in cells), (name, section)
    # the table runs differ in their file only: that column is shown there, no other data.* column
    table_header = sections[0].splitlines()[2]
    assert "data.path" in table_header and "data.errors" not in table_header and "data.variables" not in table_header
    assert max(len(line) for line in text.splitlines()) < 200
    # a configuration value that reads as a missing number is quoted
    assert "'nan'" in report.to_markdown(rows, report.select_columns(rows, "data.errors"))


def test_the_report_csv_leaves_missing_values_empty(three_systems):
    from mosd.app import report

    rows = report.collect(three_systems)
    text = report.to_csv(rows)
    assert "–" not in text
    parsed = list(csv.DictReader(io.StringIO(text)))
    tep = next(r for r in parsed if r["system"] == "data=tep")
    # a run without the key, a metric not logged (no CI of one test run): empty; a value is itself
    assert tep["data.path"] == "" and tep["far_ci"] == "" and tep["far"] == repr(0.02)
    assert {r["data.errors"] for r in parsed if r["system"] == "data=table"} == {"nan"}


# -- 4. the figures ----------------------------------------------------------------------------------
def _drawn(monkeypatch):
    from mosd.app import figures as plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or Path(path))
    return plots, figures


def test_the_chart_marks_every_fault_onset_and_keeps_its_title_inside(monkeypatch, tmp_path):
    plots, figures = _drawn(monkeypatch)
    t = np.arange(400.0)
    mask = np.zeros(400, bool)
    for start in (100, 200, 300):
        mask[start:start + 30] = True
    title = "pca on data=table: " + ", ".join(f"parameter_{i} = {0.1 * i:.4g}" for i in range(8))
    plots.chart_trace(tmp_path / "chart.png", t, np.ones(400), np.full(400, 2.0), mask, title=title)
    (fig,) = figures
    ax = fig.axes[0]
    onsets = [line for line in ax.lines if line.get_linestyle() == ":"]
    assert sorted(line.get_xdata()[0] for line in onsets) == [100, 200, 300]
    fig.canvas.draw()
    box = ax.title.get_window_extent(fig.canvas.get_renderer())
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width, (box, fig.bbox.width)


def test_the_pareto_legend_leaves_the_chosen_design_visible(monkeypatch, tmp_path):
    plots, figures = _drawn(monkeypatch)
    far = np.linspace(0.0, 0.3, 20)
    F = np.column_stack([far, (0.3 - far) ** 2 * 3])
    for chosen in (0, 10, 19):
        figures.clear()
        plots.pareto_front(tmp_path / "pareto.png", F, chosen=chosen, title="Archive of mopso")
        (fig,) = figures
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        legend = fig.legends[0].get_window_extent(renderer)
        ax = fig.axes[0]
        star = ax.transData.transform(F[chosen])
        assert not legend.contains(*star), (chosen, legend, star)


# -- 2. names, 4. git ------------------------------------------------------------------------------------
def test_runs_are_named_by_what_they_are():
    from omegaconf import OmegaConf

    from mosd.app.run import run_name

    table = OmegaConf.create({"data": {"path": "/x/plant.csv"}})
    assert run_name(table, {"experiment": "table", "data": "table", "detector": "pca", "optimizer": "mopso"}) \
        == "table:plant-pca-mopso"
    assert run_name(table, {"experiment": "", "data": "table", "detector": "pca", "optimizer": "mopso"}) \
        == "table:plant-pca-mopso"
    assert run_name(OmegaConf.create({}), {"experiment": "tep", "data": "tep", "detector": "pca",
                                           "optimizer": "mopso"}) == "tep-pca-mopso"
    assert run_name(OmegaConf.create({}), {"experiment": "paper002", "fault": "target_nuisance",
                                           "detector": "threshold", "optimizer": "mopso"}) == "paper002-threshold-mopso"
    assert run_name(OmegaConf.create({}), {"experiment": "", "fault": "offset_var", "detector": "ss_dewma",
                                           "optimizer": "nsga2"}) == "offset_var-ss_dewma-nsga2"


def test_the_git_commit_is_found_from_a_package_inside_the_checkout(tmp_path):
    from mosd.app.mlflow_client import git_commit

    package = tmp_path / "checkout" / "mosd" / "app"
    package.mkdir(parents=True)
    (package.parent / "__init__.py").write_text("")
    git = ["git", "-C", str(tmp_path / "checkout")]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "-c", "user.email=a@b", "-c", "user.name=a", "add", "."], check=True)
    subprocess.run([*git, "-c", "user.email=a@b", "-c", "user.name=a", "commit", "-qm", "x"], check=True)
    head = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    assert git_commit(package.parent) == head
    assert git_commit(tmp_path / "checkout" / "venv" / "lib" / "site-packages" / "mosd") is None
    # this package, in this checkout
    repo = Path(__file__).resolve().parents[1]
    if (repo / ".git").exists():
        here = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True)
        assert git_commit() == here.stdout.strip()


# -- 3. the TE files as CSV ------------------------------------------------------------------------------
def test_the_te_files_export_as_csv_with_their_tag_names(tmp_path):
    from mosd.data.tep import PRESETS, TennesseeEastman
    from mosd.systems.tep import main

    assert main(["--export", str(tmp_path / "te")]) == 0
    files = sorted((tmp_path / "te").glob("d*.csv"))
    assert len(files) == 44 and {"d00.csv", "d21.csv", "d00_te.csv", "d21_te.csv"} <= {f.name for f in files}
    # each value is written as repr(float) and parsed back correctly rounded ("round_trip"; pandas' default
    # parser is faster, not correctly rounded), so the CSV holds the raw file's float64s exactly
    frame = pd.read_csv(tmp_path / "te" / "d05_te.csv", float_precision="round_trip")
    assert list(frame.columns) == ["time", "fault", *PRESETS["literature"]]
    assert (frame["fault"][:160] == 0).all() and (frame["fault"][160:] == 5).all()
    assert frame["time"][1] - frame["time"][0] == 180.0
    raw = TennesseeEastman().values("d05_te.dat")
    np.testing.assert_array_equal(frame[list(PRESETS["literature"])].to_numpy(), raw)
    assert (pd.read_csv(tmp_path / "te" / "d07.csv")["fault"] == 7).all()


def test_the_te_export_table_runs_as_printed(tmp_path, capsys):
    """issue 51: `--export` then `+experiment=table data.path=DIR/d05_te.csv` exited 2 (a split with no fault-free
    row); the export now writes the preset's splits as one table and prints the command that runs it."""
    import shlex

    from mosd.systems.tep import main

    assert main(["--export", str(tmp_path / "te")]) == 0
    command = [line.strip() for line in capsys.readouterr().out.splitlines() if "+experiment=table" in line]
    assert len(command) == 1, command
    table = pd.read_csv(tmp_path / "te" / "te_table.csv")
    assert len(table) == 500 + 960 + 18 * 480 + 18 * 960 and (np.diff(table["time"]) == 180.0).all()
    argv = shlex.split(command[0])
    assert argv[:3] == ["python", "-m", "mosd"]
    run = subprocess.run([sys.executable, *argv[1:], "debug=tiny", "tracking=none", "progress=false"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "FAR" in run.stdout and "MDR" in run.stdout


# -- 5. set-up: compile what a run needs ----------------------------------------------------------
def test_kernels_compile_by_module(tmp_path):
    from test_app import PACKAGE_PARENT

    env = {"PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "PYTHONPATH": PACKAGE_PARENT,
           "HOME": str(tmp_path)}
    cli = subprocess.run([sys.executable, "-m", "mosd.kernels", "--modules", "ewma", "--jobs", "1"], env=env,
                         capture_output=True, text=True, timeout=300)
    assert cli.returncode == 0 and "1 of 1 kernel modules ready" in cli.stderr, cli.stderr
    bad = subprocess.run([sys.executable, "-m", "mosd.kernels", "--modules", "nope"], env=env,
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "allowed: ewma, wavelet, chart" in bad.stderr
    script = "from mosd import kernels; print([m for m in kernels.MODULES if kernels.cached(m)])"
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "['ewma']", out.stderr[-3000:]  # only what was asked for


@pytest.mark.slow
def test_the_main_command_on_a_cold_cache_compiles_only_the_kernels_it_calls(tmp_path):
    """The set-up runs no ``python -m mosd.kernels``: the first run compiles what it calls, not the wavelet, IMM
    or entropy."""
    from test_app import PACKAGE_PARENT

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert "pip install . && python -m mosd +fault=offset_var optimizer=mopso" in readme
    env = {"PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "PYTHONPATH": PACKAGE_PARENT,
           "HOME": str(tmp_path), "MOSD_OUTPUTS": str(tmp_path / "outputs")}
    # numba reports each kernel it saves on the saving process's stdout: the run's own here, the second
    # process's (mosd.kernels.ahead) go to the run, which keeps only its ready/failed lines
    run = subprocess.run([sys.executable, "-m", "mosd", "+fault=offset_var", "tracking=none", *SMALL,
                          "budget.n_test=2", "budget.n_train=2", "budget.n_calibration=2"], cwd=tmp_path,
                         env={**env, "NUMBA_DEBUG_CACHE": "1"}, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    saved_here = set(re.findall(r"\[cache\] data saved to '[^']*?([A-Za-z_]+)-\d+\.py", run.stdout))
    assert {"cesckf", "simulate_mould_oscillator"} <= saved_here, run.stdout[-3000:]
    handed_over = {"_tria_lanes", "_update_lanes", "alarm_counts", "ewma_population", "particle_move", "offspring"}
    if len(os.sched_getaffinity(0)) >= 2:  # compiled ahead in the second process, loaded here: saved there only
        assert not saved_here & handed_over, saved_here & handed_over
    else:  # one CPU: no second process, everything compiles here
        assert handed_over <= saved_here, saved_here
    script = "from mosd import kernels; print(' '.join(m for m in kernels.MODULES if kernels.cached(m)))"
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    # denoise=none: the wavelet's chart kernel (and the wavelet) are left for a run that denoises
    assert set(out.stdout.split()) == {"ewma", "chart", "plants", "cubature", "swarm"}, out.stdout


def test_a_single_run_prints_its_results_before_its_files_and_mlflow(tmp_path):
    """The results (chosen … delay) are printed as soon as the test is scored; where the files and the MLflow
    run are, once they are. A sweep still prints each job's summary whole."""
    from test_app import PACKAGE_PARENT

    script = ("import sys\n"
              "import mosd.app.run as run\n"
              "written = run.write_run_files\n"
              "def announced(*args, **kwargs):\n"
              "    print('FILES START', flush=True)\n"
              "    return written(*args, **kwargs)\n"
              "run.write_run_files = announced\n"
              "from mosd.app import main\n"
              "sys.exit(main())\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env.update(PYTHONPATH=PACKAGE_PARENT, MOSD_OUTPUTS=str(tmp_path / "outputs"))
    done = subprocess.run([sys.executable, "-c", script, "+fault=offset", "tracking=none", *SMALL, "budget.n_test=2",
                           "budget.n_train=2", "budget.n_calibration=2"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = [line.split()[0] for line in done.stdout.splitlines() if line.strip()]
    assert lines.index("FAR") < lines.index("delay") < lines.index("FILES") < lines.index("wall") < lines.index("run")
    assert lines[0] == "mosd" and lines.count("FAR") == 1

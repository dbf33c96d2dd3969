"""The run directory: resolved config, Pareto set and history (CSV), ``summary.json`` and the figures.

The figures are the slow part: they are submitted first to the figure process
(:class:`mosd.app.plots.FigureWriter`) and drawn there while this module writes
the text files; MLflow takes the text files meanwhile (``on_text_files``). A run
that does not finish leaves a ``summary.json`` that says so (:func:`write_status`).

Every file is written through a temporary file and an atomic rename
(:func:`mosd.app.atomic.write_atomically`): a full disk leaves a file complete or absent, never
cut short. A run whose directory cannot be written (disk full, quota) ends with
one line, exit code 1 (:data:`NOT_WRITTEN`) and a ``summary.json``, if even that
can be written, that lists what the directory lacks.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np
from hydra.experimental.callback import Callback

from .atomic import write_atomically, write_json
from .settings import redacted
from .summary import on_bound

if TYPE_CHECKING:
    from .build import Setup


#: Run directories of this process that could not be written (:func:`mosd.app.main` exits 1); a sweep's
#: jobs in other processes are found from their ``summary.json`` (:class:`mosd.app.sweep.SweepCallback`).
NOT_WRITTEN: list[Path] = []


def expected_files(run_dir: Path, result, setup: Setup, labels: Mapping[str, str]) -> list[Path]:
    """The files :func:`write_run_files` writes for ``result`` (the study's own files aside)."""
    text = ["resolved_config.yaml", "pareto.csv", *(["history.csv"] if result.history else []), "summary.json"]
    return [*(run_dir / name for name in text), *(kwargs["path"] for _, kwargs in figure_jobs(run_dir, result, setup,
                                                                                              labels))]


def lacking(run_dir: Path, expected: list[Path]) -> list[str]:
    """The names of the ``expected`` files ``run_dir`` lacks; removes the temporary files of unfinished writes.

    For a run stopped while writing (its figure process killed mid-PNG, whose
    temporary file :func:`write_atomically` had no chance to remove).
    """
    for path in expected:
        for leftover in run_dir.glob(f".{path.stem}-*{path.suffix}"):
            try:
                leftover.unlink()
            except OSError:
                pass
    return [p.name for p in expected if not p.exists()]


def write_run_files(run_dir: Path, cfg, result, setup: Setup, labels: Mapping[str, str],
                    study: Mapping[str, float] | None = None, figures=None,
                    on_text_files: Callable[[list[Path]], None] | None = None,
                    extra_figures: Sequence[tuple[str, dict]] = ()) -> list[Path]:
    """Resolved config, Pareto set and history as CSV, summary JSON and the PNG plots.

    ``figures``: a :class:`mosd.app.plots.FigureWriter` (started with the run) that
    draws the PNGs in its side process while this writes the other files; None
    draws them here. ``on_text_files`` is called with the text files once they
    are written, before the figures are waited for (MLflow takes them meanwhile).
    ``extra_figures``: more figure jobs drawn with the run's (a study's: :func:`mosd.app.plots.study_figures`).
    """
    from omegaconf import OmegaConf

    from . import plots

    run_dir.mkdir(parents=True, exist_ok=True)
    F = result.archive_F
    objectives = list(result.objectives)
    # the figures first: they are the slow part, drawn while the text files are written
    jobs = [*figure_jobs(run_dir, result, setup, labels), *extra_figures]
    if figures is not None:
        figures.submit(jobs)
    written = []
    written.append(write_atomically(run_dir / "resolved_config.yaml",
                                    lambda out: out.write(redacted(OmegaConf.to_yaml(cfg, resolve=True)))))

    names = list(result.params)
    order = np.argsort(F[:, 0], kind="stable")
    columns = [result.archive_X[order], F[order]]
    header = [*names, *objectives]
    if objectives == ["far", "mdr"]:
        columns.append(1.0 - F[order].sum(axis=1))
        header.append("accuracy")
    table = np.column_stack([*columns, (order == result.chosen_index).astype(float)])
    written.append(write_atomically(run_dir / "pareto.csv", lambda out: np.savetxt(
        out, table, delimiter=",", header=",".join([*header, "chosen"]), comments="",
        fmt=["%.10g"] * (table.shape[1] - 1) + ["%d"])))

    if result.history:
        keys = list(result.history[0])
        rows = np.array([[r[k] for k in keys] for r in result.history], float)
        written.append(write_atomically(run_dir / "history.csv", lambda out: np.savetxt(
            out, rows, delimiter=",", header=",".join(keys), comments="", fmt="%.10g")))

    summary = result.summary()
    written.append(write_json(run_dir / "summary.json", {
        "status": "finished",
        "labels": dict(labels),
        "params": result.params,
        "online": bool(setup.experiment.detector.is_causal),
        "on_bound": on_bound(result.params, setup),
        "objectives": list(result.objectives),
        "train": dict(result.train_objectives),
        "test": test_block(summary),
        "sigma": result.sigma,
        # recorded data: which rows of which recording each split used (mosd.data)
        **({"data": setup.experiment.describe()} if hasattr(setup.experiment, "describe") else {}),
        **({"study": dict(study)} if study else {}),
        "timings": result.timings,
    }))
    if on_text_files is not None:
        on_text_files(list(written))
    written += figures.result() if figures is not None else plots.draw(jobs)
    return written


def test_block(summary: Mapping[str, Any]) -> dict[str, dict]:
    """``summary.json``'s ``"test"``: per metric its mean, CI half-width, runs and, for a delay, its unit.

    A metric no test run defines (``n`` = 0) is not written, except the accuracy of recorded
    data, where every run is all fault-free or all faulty: there it is 1 − mean FAR − mean MDR, as
    the console prints it (:func:`mosd.app.summary.final_metrics`), without a CI.
    """
    from ..metrics.registry import METRICS
    from ..metrics.summary import accuracy

    block = {}
    for key, value in summary.items():
        unit = METRICS[key].unit if key in METRICS else ""
        if value.n:
            block[key] = {"mean": value.mean, "ci95_half_width": value.half_width, "n": value.n,
                          **({"unit": unit} if unit else {})}
    if "accuracy" in summary and "accuracy" not in block and {"far", "mdr"} <= set(block):
        block["accuracy"] = {"mean": accuracy(block["far"]["mean"], block["mdr"]["mean"]),
                             "ci95_half_width": None, "n": 0, "of": "1 - mean far - mean mdr (no run has both)"}
    return block


def figure_jobs(run_dir: Path, result, setup: Setup, labels: Mapping[str, str]) -> list[tuple[str, dict]]:
    """The run's figures as ``(name in mosd.app.plots, keyword arguments)`` (plain arrays: picklable)."""
    F = result.archive_F
    objectives = tuple(result.objectives)
    ex = result.example
    monitor = setup.experiment.monitor
    # recorded data (data=...) have no fault option: the data source names the run
    subject = f"data={labels['data']}" if labels.get("data") else f"{labels.get('fault', '')} fault"
    title = f"{labels.get('detector', '')} on {subject}: " + ", ".join(
        f"{k} = {v:.4g}" for k, v in result.params.items())
    archive_title = f"Archive of {labels.get('optimizer', '')} (training replications)"
    jobs = [("pareto_front" if F.shape[1] == 2 else "pareto_pairs",
             dict(path=run_dir / "pareto.png", F=F, chosen=result.chosen_index, title=archive_title,
                  labels=objectives))]
    t = ex["t"] if ex.get("t") is not None else np.arange(len(ex["statistic"])) * ex["seconds_per_point"]
    jobs.append(("chart_trace", dict(path=run_dir / "chart.png", t=t, statistic=ex["statistic"], ucl=ex["ucl"],
                                     fault_mask=ex["fault_mask"], title=title)))
    channel = getattr(setup.experiment.fault, "channel", 0)
    if ex.get("residual") is not None:
        channels = getattr(monitor, "channels", ())
        mean = float(monitor.mean_[channels.index(channel)]) if channel in channels and hasattr(monitor, "mean_") \
            else 0.0
        names = tuple(getattr(setup.experiment.plant, "output_names", ()))
        jobs.append(("residual_trace", dict(path=run_dir / "residual.png", residual=ex["residual"],
                                            fault_mask=ex["residual_fault_mask"], dt=ex["dt"], mean=mean,
                                            sigma=result.sigma,
                                            channel_name=names[channel] if channel < len(names) else "")))
    if result.history:
        n_eval = int(result.history[-1].get("n_eval", 0))
        jobs.append(("optimisation_history", dict(
            path=run_dir / "history.png", records=result.history,
            title=f"{labels.get('optimizer', '')} on {'' if labels.get('data') else 'the '}{subject}: "
                  f"{len(result.history)} "
                  f"generations, {n_eval} evaluations (training replications)")))
    return jobs



def write_status(run_dir: Path, status: str, labels: Mapping[str, str], error: str | None = None,
                 **extra: Any) -> Path:
    """``summary.json`` of a run that did not finish (``killed``, ``failed``): never a silent stub."""
    run_dir.mkdir(parents=True, exist_ok=True)
    return write_json(run_dir / "summary.json", {"status": status, "labels": dict(labels),
                                                 **({"error": error} if error else {}), **extra})


def redact_file(path: Path) -> None:
    """Mask URI passwords in a text file, replacing it atomically (concurrent jobs may rewrite the same one)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError):
        return
    masked = redacted(text)
    if masked != text:
        write_atomically(path, lambda out: out.write(masked))


class RedactConfigFiles(Callback):
    """Hydra callback: masks a password in ``tracking.uri`` in the config files Hydra saved for the job.

    Hydra writes ``.hydra/{config,hydra,overrides}.yaml`` (and a sweep's
    ``multirun.yaml``) before the job starts, with the overrides as typed; the job
    reads its config from memory, so the files are masked before any work.
    """

    def on_job_start(self, config, **kwargs: Any) -> None:
        hc = config.hydra
        places = []
        if hc.output_subdir is not None:
            places += sorted((Path(hc.runtime.output_dir) / str(hc.output_subdir)).glob("*.yaml"))
        if hc.mode is not None and str(hc.mode).endswith("MULTIRUN"):
            places.append(Path(hc.sweep.dir) / "multirun.yaml")
        for path in places:
            if path.is_file():
                redact_file(path)

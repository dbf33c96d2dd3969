"""A finished run's deployable pipeline and its test stream: built from the components' causal forms, no list.

:func:`deployable` asks each stage of the run for its causal form (:mod:`mosd.streaming`):
``Estimator.online``, ``Monitor.online`` and ``Detector.online``. No component is named here: a new
detector that implements ``online`` is deployed with no change to the app. Where a stage has none the
answer is one line saying why (the run's summary prints it):

* the estimator has none (no preset's estimator today: the CESCKF dedicated observer, the IMM, the
  gain filters and the observers stream the plant's raw ``y_<output>``/``u_<input>`` columns or
  packets, and on recorded data the PCA residual generator its tags): the pipeline starts at the
  monitor and the model's input is the estimator's output stream; the summary says so;
* the monitor or the detector has none (paper 000's whole-series wavelet, MS-OEWMA's prefilter):
  no model (the test stream is still written when the monitor streams).

The run's first test replication — the model's input columns, the time and the run's own decision on
each row — is written as ``test_stream.parquet``; ``python -m mosd monitor --model URI
test_stream.parquet`` reproduces its ``alarm`` column exactly. Before anything is saved, the pipeline
scores that stream in-process and must give the run's own decisions on every row: a disagreement is
reported (no model) rather than deployed.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..streaming import NoStreamingForm, OnlinePipeline

STREAM_FILE = "test_stream.parquet"
#: the DataFrame attribute (kept in the Parquet file) naming a test stream's reference columns
REFERENCE_ATTR = "mosd_reference"
#: the Parquet schema-metadata key whose JSON ``pandas.read_parquet`` restores as ``DataFrame.attrs``
#: (pandas >= 2.1 writes and reads it): the stream is written by pyarrow alone (:func:`write_stream`)
PANDAS_ATTRS_KEY = b"PANDAS_ATTRS"


@dataclass
class Deployable:
    """What :func:`deployable` found: the pipeline (or None and why), the test stream, a note on its input."""

    pipeline: OnlinePipeline | None
    reason: str | None = None
    note: str | None = None
    stream: dict | None = None   # column -> NumPy array, in file order: time, the inputs, the decision and alarm


def deployable(setup, result) -> Deployable:
    """The run's pipeline and test stream (module docstring)."""
    experiment = setup.experiment
    example = getattr(result, "example", None) or {}
    outputs = example.get("first_outputs")
    if outputs is None or "calibration_z" not in example:
        return Deployable(None, "the run kept no test stream")
    estimator, monitor, detector = experiment.estimator, experiment.monitor, result.detector
    note, stages, raw = None, [], None
    try:
        raw, stage = _estimator_stage(experiment, estimator)
        if stage is not None:
            stages.append(stage)
    except NoStreamingForm as exc:
        note = f"model input: the estimator's outputs ({exc})"
    try:
        columns = monitor.stream(outputs, estimator.residual_columns(outputs))
        monitor_stage = monitor.online(tuple(columns))
    except NoStreamingForm as exc:
        return Deployable(None, str(exc))
    index = _points(monitor_stage, columns)
    stream = _stream(index, raw if stages else columns, outputs, np.asarray(example["decision"]))
    try:
        detector_stage = detector.online(np.asarray(example["calibration_z"]), tuple(columns))
    except NoStreamingForm as exc:
        return Deployable(None, str(exc), None, stream)
    stages += [monitor_stage, detector_stage]
    pipeline = OnlinePipeline(stages, fill=str(getattr(getattr(experiment, "data", None), "fill", "none")))
    scored = pipeline.update({k: stream[k] for k in pipeline.inputs})
    name = "decision" if "decision" in scored else "alarm"
    got, expected = np.asarray(scored[name]), stream[name]
    if not np.array_equal(got, expected):
        row = int(np.flatnonzero(got != expected)[0])
        return Deployable(None, f"its streaming form disagrees with the run's own decision at row {row} of the "
                                f"first test replication (a bug: please report it)", note, stream)
    return Deployable(pipeline, None, note, stream)


def _estimator_stage(experiment, estimator):
    """(the raw columns of the first test replication, the estimator's causal form), or (None, None) when
    its outputs are the data themselves; :class:`NoStreamingForm` when it has no causal form."""
    from ..streaming import describe

    plant, noise = getattr(experiment, "plant", None), getattr(experiment, "noise", None)
    if plant is None or noise is None or getattr(experiment, "data", None) is not None:
        stage = estimator.online(getattr(experiment, "model", None))   # recorded data: measured signals or none
        if stage is None:
            return None, None
        # a stage on the recorded tags (the PCA residual): the test split's first run, raw
        return estimator.raw_stream(experiment.simulate(None, 1, "test"), None, ()), stage
    input_names = tuple(getattr(plant, "input_names", ()) or ())
    source = {"plant": describe(plant), "noise": describe(noise), "input_names": input_names}
    # the first test replication again (seed streams: replication 0 whatever the batch), raw
    trace = experiment.simulate(experiment.fault, 1, "test")
    stage = estimator.online(experiment.model, source, trace)
    return (estimator.raw_stream(trace, experiment.model, input_names) if stage is not None else None), stage


def _points(monitor_stage, columns: dict) -> np.ndarray:
    """The point number of each row (0 off the points), as the monitor's causal form numbers them."""
    return monitor_stage.update({k: np.asarray(v) for k, v in columns.items()}, monitor_stage.initial_state())["point"]


def _stream(points: np.ndarray, columns: dict, outputs, decision: np.ndarray) -> dict:
    """Time, the input columns and the run's own decision/alarm on each row (0/False off the points)."""
    # imported now, while the app waits for the figures (it builds the stream then); written after them
    import pyarrow.parquet  # noqa: F401

    rows = len(points)
    at = np.flatnonzero(points > 0)
    per_row = np.zeros(rows, np.int64)
    per_row[at] = decision[points[at] - 1]
    t = np.asarray(outputs.t, float) if outputs.t is not None else np.arange(rows, dtype=float)
    return {"t": t, **{k: np.asarray(v, float) for k, v in columns.items()}, "decision": per_row, "alarm": per_row > 0}


def write_stream(stream: dict, out) -> None:
    """Write a test stream (:func:`_stream`) to ``out`` as Parquet, with pyarrow and without pandas.

    ``pandas.read_parquet`` (``mosd monitor``) reads it back as the DataFrame pandas' own writer left:
    the same columns and dtypes, a RangeIndex, and ``attrs[REFERENCE_ATTR]`` (the columns that are not
    the model's inputs, kept beside its output as ``run_<name>``) from the schema metadata. The columns
    are handed to Arrow as buffers: ``pyarrow.array`` on a NumPy array imports pandas when it is
    installed, 0.65–1.1 s of a warm run's files phase on the project's 2-core machine.
    """
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    def column(values: np.ndarray):
        values = np.ascontiguousarray(values)
        if values.dtype == bool:   # Arrow's booleans are bits, least significant first
            return pa.Array.from_buffers(pa.bool_(), len(values),
                                         [None, pa.py_buffer(np.packbits(values, bitorder="little"))])
        return pa.Array.from_buffers(pa.from_numpy_dtype(values.dtype), len(values), [None, pa.py_buffer(values)])

    attrs = {REFERENCE_ATTR: ["t", "decision", "alarm"]}
    table = pa.Table.from_arrays([column(v) for v in stream.values()], names=list(stream))
    pq.write_table(table.replace_schema_metadata({PANDAS_ATTRS_KEY: json.dumps(attrs).encode()}), out)


def save_for_run(setup, result, run_dir, found: Deployable | None = None) -> tuple[Path | None, Deployable]:
    """Save the run's pipeline under ``run_dir/model/`` and its test stream beside it (module docstring).

    Returns the model file (None: no model) and what :func:`deployable` found. ``found``: what
    :func:`deployable` already returned (the app builds it while its figures are drawn).
    """
    from .atomic import write_atomically

    found = deployable(setup, result) if found is None else found
    run_dir = Path(run_dir)
    if found.stream is not None:
        write_atomically(run_dir / STREAM_FILE, lambda out: write_stream(found.stream, out), binary=True)
    if found.pipeline is None:
        return None, found
    return found.pipeline.save(run_dir / "model"), found


def record_model(run_dir, found: Deployable, model_file: Path | None, uri: str | None = None) -> None:
    """Say in ``summary.json`` what was deployed: ``model`` (the MLflow model URI once logged, else null), the
    saved file, the test stream, and why there is no model or what its input is."""
    import json

    from .atomic import write_json

    path = Path(run_dir) / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, ValueError):
        return
    summary["model"] = uri
    summary["deployment"] = {
        "model_file": None if model_file is None else str(Path(model_file).relative_to(run_dir)),
        "test_stream": STREAM_FILE if found.stream is not None else None,
        **({"no_model": found.reason} if found.reason else {}),
        **({"input": found.note} if found.note else {}),
    }
    write_json(path, summary)

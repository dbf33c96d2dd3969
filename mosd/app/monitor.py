"""``python -m mosd monitor --model MODEL_URI DATA.csv|DATA.parquet [--out alarms.csv]``: score a file.

The model is a run's logged detector (:mod:`mosd.app.detector_model`), loaded with
``mlflow.pyfunc.load_model``. The file's rows are scored in chunks of
``--chunk`` rows, in file order; each chunk starts from the state the previous
chunk ended with (the model's params: for PCA the EWMA of T² and SPE and the
consecutive points above the limit; for a chart on a residual stream,
:mod:`mosd.app.chart_model`, the samples seen, the smoothed U and V and the
unfinished subgroup), so the alarms do not depend on the chunk size. A cell that is not a number (a
historian error code such as ``Bad``) is a missing value, and the run's
``data.fill`` policy (stored in the model) fills the file as training did
(``hold``, ``interpolate``, ``drop``); with ``none`` (and for TE) a row with a
missing value gets no alarm and the EWMA takes the in-control mean there.

Exit codes: 0 done; 2 a mistake (one line: no such model or file, a missing or
an extra column).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from ..validation import ConfigError
from .settings import default_tracking_uri, redacted

PROG = "python -m mosd monitor"


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse prints the usage first)
        print(f"mosd monitor: error: {redacted(message)}", file=sys.stderr)
        raise SystemExit(2)


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Score a CSV/Parquet file with a run's logged detector model.")
    p.add_argument("data", help="a .csv (.csv.gz) or .parquet file: one row per sample, the model's tag columns")
    p.add_argument("--model", required=True, help="the model URI (models:/M-ID or runs:/RUN_ID/detector, "
                   "printed in the run's summary)")
    p.add_argument("--out", default=None, help="write the per-row output (statistics, limits, alarm, top "
                   "variables, state) to this CSV")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI, "
                   f"else {default_tracking_uri()})")
    p.add_argument("--keep", action="append", default=[], metavar="COLUMN",
                   help="a column that is not a tag (time, label): copied to the output, not scored (repeatable)")
    p.add_argument("--chunk", type=int, default=1000, help="rows per predict call (state carried across)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def _load(uri: str, tracking_uri: str):
    import logging

    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    import mlflow

    logging.getLogger("mlflow").setLevel(logging.ERROR)

    mlflow.set_tracking_uri(tracking_uri)
    try:
        return mlflow.pyfunc.load_model(uri)
    except Exception as exc:
        text = " ".join(str(exc).split())
        raise ConfigError(f"--model={uri!r} cannot be loaded from {tracking_uri}: {type(exc).__name__}: "
                          f"{text[:300]}; allowed: the model URI a mosd run printed") from None


def _plain(value):
    """A NumPy scalar as the Python number MLflow's params accept."""
    return value.item() if hasattr(value, "item") else value


def score_file(model, frame, chunk: int = 1000, progress: bool = False):
    """The model's output for every row of ``frame``, scored in chunks with the state carried."""
    import pandas as pd

    parts, state = [], None
    schema = model.metadata.get_params_schema() if hasattr(model, "metadata") else None
    # the carried state: the params of the model's signature, each an output column of every row
    names = [p.name for p in schema.params] if schema is not None else ["ewma_t2", "ewma_spe", "run_length"]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(frame), unit="row", desc="monitor", file=sys.stderr)
    for start in range(0, len(frame), chunk):
        out = model.predict(frame.iloc[start:start + chunk], params=state)
        parts.append(out)
        state = {name: _plain(out[name].iloc[-1]) for name in names}
        if bar is not None:
            bar.update(len(out))
    if bar is not None:
        bar.close()
    return pd.concat(parts) if parts else model.predict(frame)


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        from ..data.table import _read
        from .deploy import REFERENCE_ATTR

        if args.chunk < 1:
            raise ConfigError(f"--chunk={args.chunk} is out of range; allowed: integers >= 1")
        path = Path(args.data).expanduser()
        try:
            frame = _read(path)
        except ConfigError as exc:
            raise ConfigError(str(exc).replace("data.path=", "DATA=")) from None
        frame.columns = [str(c) for c in frame.columns]
        # a run's test_stream.parquet: its time and the run's own decisions come along as run_<name>
        reference = [c for c in frame.attrs.get(REFERENCE_ATTR, ()) if c in frame.columns and c not in args.keep]
        missing = [c for c in args.keep if c not in frame.columns]
        if missing:
            raise ConfigError(f"--keep {missing[0]!r} is not a column of {path}; allowed: {', '.join(frame.columns[:8])}")
        tracking = args.tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()
        model = _load(args.model, tracking)
        tags = frame.drop(columns=[*args.keep, *reference])
        # MLflow's schema enforcement would drop an extra column with a warning: here it is a mistake
        names = model.metadata.get_input_schema().input_names()
        for kind, found in (("is missing", [n for n in names if n not in tags.columns]),
                            ("is not a tag of the model", [c for c in tags.columns if c not in names])):
            if found:
                raise ConfigError(f"column {found[0]!r} of {path} {kind} ({len(found)} such); allowed: the model's "
                                  f"{len(names)} tags in any order, other columns named with --keep")
        fill = getattr(getattr(model.unwrap_python_model(), "fitted", None), "fill", "none")
        if fill != "none":
            # the training data's policy for historian error codes and gaps (mosd.data.table), on the whole file
            import pandas as pd

            from ..data.table import _fill

            values = np.column_stack([pd.to_numeric(tags[c], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
                                      for c in tags.columns])
            values, _, kept = _fill(values, np.zeros(len(values), int), fill)
            frame = frame.iloc[kept]
            tags = pd.DataFrame(values, columns=tags.columns, index=frame.index)
        try:
            out = score_file(model, tags, args.chunk, progress=not args.no_progress and sys.stderr.isatty())
        except ConfigError:
            raise
        except Exception as exc:  # MLflow wraps the model's ConfigError (schema enforcement, or predict)
            cause = exc
            while cause.__cause__ is not None or cause.__context__ is not None:
                if isinstance(cause, ConfigError):
                    break
                cause = cause.__cause__ or cause.__context__
            raise ConfigError(" ".join(str(cause if isinstance(cause, ConfigError) else exc).split())) from None
    except ConfigError as exc:
        print(f"mosd monitor: error: {redacted(str(exc))}", file=sys.stderr)
        return 2
    for column in args.keep:
        out.insert(0, column, frame[column].to_numpy())
    for column in reversed(reference):
        out.insert(0, column if column == "t" else f"run_{column}", frame[column].to_numpy())
    alarms = out["alarm"].to_numpy(bool)
    if "subgroup" in out.columns:  # a chart decides once per completed subgroup
        decided = int((out["subgroup"].to_numpy() > 0).sum())
        print(f"{path}: {len(out)} rows, {int(alarms.sum())} alarms in {decided} subgroups "
              f"({alarms.sum() / decided if decided else 0:.4f} of them)")
    else:
        print(f"{path}: {len(out)} rows, {int(alarms.sum())} alarms ({alarms.mean() if len(out) else 0:.4f} of rows)")
    if alarms.any():
        first = int(alarms.argmax())
        row = out.iloc[first]
        if "statistic" in out.columns:  # a chart or a threshold on a residual stream
            where = f" (subgroup {row['subgroup']})" if "subgroup" in out.columns else ""
            print(f"first alarm at row {first}{where}: statistic {row['statistic']:.4g} (limit {row['limit']:.4g})")
        else:
            print(f"first alarm at row {first}: T² {row['t2']:.4g} (limit {row['t2_limit']:.4g}), SPE "
                  f"{row['spe']:.4g} (limit {row['spe_limit']:.4g}); top T² {row['top_t2']}, top SPE {row['top_spe']}")
    if "alarm" in reference:
        same = int(np.sum(out["run_alarm"].to_numpy(bool) == alarms))
        print(f"the run's own alarms: {same} of {len(out)} rows agree"
              + ("" if same == len(out) else " (the model does not reproduce its run)"))
    if args.out:
        out.to_csv(args.out, index=False)
        print(f"per-row output: {args.out}")
    return 0

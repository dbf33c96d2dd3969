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

Before any scoring, and before MLflow is imported: ``--out`` must be a file in an existing,
writable directory (a real write is tried, as :func:`mosd.app.checks.writable_dir_problem` does),
and a ``models:/`` or ``runs:/`` model's store must exist (a sqlite file holding an MLflow store, a
store directory): a mistyped ``--tracking-uri`` is one line naming the store's path, and creates
nothing (MLflow would create an empty store there). ``DATA`` may be ``-``: the file comes on stdin
(CSV, or Parquet by its magic bytes). ``--keep`` columns come first in the output, in the order given.
The output file is written whole or not at all (:mod:`mosd.app.atomic`).

Exit codes: 0 done; 2 a mistake (one line: no such model, store or file, an output path that
cannot be written, a missing or an extra column, a state param out of its domain); 1 the output
could not be written after scoring (disk full; nothing is left half-written).
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
    p.add_argument("data", nargs="?", default=None, help="a .csv (.csv.gz) or .parquet file: one row per sample, "
                   "the model's tag columns (- : read it from stdin); not with --opcua")
    p.add_argument("--model", required=True, help="the model URI (models:/M-ID or runs:/RUN_ID/detector, "
                   "printed in the run's summary)")
    p.add_argument("--out", default=None, help="write the per-row output (statistics, limits, alarm, top "
                   "variables, state) to this CSV")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI, "
                   f"else {default_tracking_uri()})")
    p.add_argument("--keep", action="append", default=[], metavar="COLUMN",
                   help="a column that is not a tag (time, label): copied to the output, not scored (repeatable)")
    p.add_argument("--chunk", type=int, default=1000, help="rows per predict call (state carried across)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (with --opcua: no reconnect lines)")
    live = p.add_argument_group("a live plant over OPC UA (pip install 'mosd[opcua]'; docs/how-to/opcua.md)")
    live.add_argument("--opcua", default=None, metavar="opc.tcp://HOST:PORT",
                      help="subscribe to this OPC UA server instead of reading a file")
    live.add_argument("--nodes", default=None, metavar="FILE.yaml", help="the model's input columns mapped to node "
                      "ids or unique browse names (default: each column's own name as a browse name)")
    live.add_argument("--write", default=None, metavar="FILE.yaml", help="output columns mapped to existing nodes "
                      "to write (default: every output, on nodes mosd creates under Objects/mosd)")
    live.add_argument("--state", default=None, metavar="state.json", help="checkpoint the state here; restarted "
                      "with the same file the monitor continues where it stopped")
    live.add_argument("--step", type=float, default=None, help="the model's sampling step in seconds (required "
                      "with --opcua): samples are aligned to it")
    live.add_argument("--interval", type=float, default=None, help="publishing interval in seconds (default: --step, "
                      "at most 1)")
    live.add_argument("--since", default=None, help="the time of the first sample to score (Unix seconds or "
                      "ISO-8601): earlier samples come from the server's history (default: the first value seen)")
    live.add_argument("--samples", type=int, default=None, help="stop after this many samples from the first "
                      "(default: run until SIGTERM/SIGINT)")
    live.add_argument("--checkpoint-every", type=int, default=100, help="samples between checkpoints (default 100)")
    live.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the server (default 10)")
    live.add_argument("--late", type=float, default=None, help="seconds a sample waits for a tag that reported "
                      "nothing newer, once a newer sample is seen; then the tag is missing (default 1 + 2 x --interval)")
    return p


def check_out(out: str | None) -> Path | None:
    """``--out`` as a path a file can be written to, or a one-line ConfigError (nothing is left behind)."""
    if out is None:
        return None
    path = Path(out).expanduser()
    allowed = "allowed: a file path in an existing, writable directory"
    if path.is_dir():
        raise ConfigError(f"--out={out!r} is a directory; {allowed}")
    parent = path.parent.resolve()
    if not parent.is_dir():
        what = "does not exist" if not parent.exists() else "is not a directory"
        raise ConfigError(f"--out={out!r}: {parent} {what}; {allowed}")
    from .checks import write_problem

    problem = write_problem(parent)
    if problem is not None:
        raise ConfigError(f"--out={out!r}: {problem}; {allowed}")
    return path


def check_store(model_uri: str, tracking_uri: str) -> None:
    """The store a ``models:/`` or ``runs:/`` URI is read from exists and holds an MLflow store (one line naming it).

    Without this, MLflow creates what a mistyped ``--tracking-uri`` names (a directory, an empty sqlite
    store) and then blames the model id. Servers (http, databases) are left to MLflow: nothing is created.
    """
    from urllib.parse import urlparse

    from .store import refusal, sqlite_path, sqlite_store_state

    if not model_uri.startswith(("models:/", "runs:/")):
        return  # a model directory: the store is not read
    allowed = "allowed: the store the mosd run logged to (tracking.uri of the run; --tracking-uri or $MLFLOW_TRACKING_URI)"
    shown = redacted(tracking_uri)
    parsed = urlparse(tracking_uri)
    if parsed.scheme == "sqlite":
        path = sqlite_path(tracking_uri)
        if path is None:
            raise ConfigError(f"--tracking-uri={shown!r} is an in-memory store: it holds no model; {allowed}")
        state = sqlite_store_state(path)
        if state.state == "missing":
            raise ConfigError(f"tracking store {path.resolve()} does not exist (--tracking-uri={shown}); {allowed}")
        if state.state == "empty":
            raise ConfigError(f"tracking store {path.resolve()} holds no MLflow store (--tracking-uri={shown}); {allowed}")
        if state.state != "ok":
            raise ConfigError(refusal(path.resolve(), state))
    elif parsed.scheme in ("", "file"):
        path = Path(parsed.path if parsed.scheme == "file" else tracking_uri).expanduser()
        if not path.is_dir():
            what = "does not exist" if not path.exists() else "is not a directory"
            raise ConfigError(f"tracking store {path.resolve()} {what} (--tracking-uri={shown}); {allowed}")
        if not any(path.glob("*/meta.yaml")):  # MLflow's file store: a meta.yaml per experiment
            raise ConfigError(f"tracking store {path.resolve()} holds no MLflow store (--tracking-uri={shown}); "
                              f"{allowed}")


def read_data(data: str):
    """The DATA argument as a DataFrame: a CSV/Parquet file, or ``-`` for stdin (one-line errors naming DATA)."""
    from ..data.table import _read

    if data != "-":
        try:
            return _read(Path(data).expanduser())
        except ConfigError as exc:
            raise ConfigError(str(exc).replace("data.path=", "DATA=")) from None
    import io

    import pandas as pd

    raw = sys.stdin.buffer.read()
    if not raw:
        raise ConfigError("DATA='-': stdin is empty; allowed: a CSV or Parquet file on stdin")
    try:
        if raw[:4] == b"PAR1":
            return pd.read_parquet(io.BytesIO(raw))
        return pd.read_csv(io.BytesIO(raw), compression="gzip" if raw[:2] == b"\x1f\x8b" else None)
    except Exception as exc:
        raise ConfigError(f"DATA='-' (stdin) cannot be read: {type(exc).__name__}: {' '.join(str(exc).split())}; "
                          "allowed: a CSV or Parquet file on stdin") from None


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


def score_file(model, frame, chunk: int = 1000, progress: bool = False, first_chunk_s: list | None = None):
    """The model's output for every row of ``frame``, scored in chunks with the state carried.

    ``first_chunk_s``: a list that gets the seconds the first chunk took (where a first call compiles its kernels).
    """
    import time

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
        t0 = time.perf_counter()
        out = model.predict(frame.iloc[start:start + chunk], params=state)
        if first_chunk_s is not None and start == 0:
            first_chunk_s.append(time.perf_counter() - t0)
        parts.append(out)
        state = {name: _plain(out[name].iloc[-1]) for name in names}
        if bar is not None:
            bar.update(len(out))
    if bar is not None:
        bar.close()
    return pd.concat(parts) if parts else model.predict(frame)


def kernels_key(fitted) -> str:
    """What decides the kernels ``mosd monitor`` compiles for a model: its pipeline's stage classes."""
    stages = getattr(fitted, "stages", None) or [fitted]
    return "monitor " + " > ".join(f"{type(s).__module__}.{type(s).__qualname__}" for s in stages)


def announce_compile(fitted) -> bool:
    """Print :func:`compile_notice` on stderr when there is one; whether it was printed."""
    notice = compile_notice(fitted)
    if notice:
        print(notice, file=sys.stderr, flush=True)
    return bool(notice)


def compile_notice(fitted) -> str | None:
    """The line printed before a first call that compiles numba kernels (issue 51: 50-70 s without a word), or None.

    None when the kernels scoring ``fitted`` needs are in numba's on-disk cache (:func:`mosd.kernels.first_call`,
    from mosd's own record in the cache folder and numba's index files), with the kernels off, or where the check
    itself fails (the line is a courtesy: scoring goes on either way).
    """
    from .. import kernels

    try:
        pending = kernels.first_call(kernels_key(fitted))
    except Exception:  # noqa: BLE001 - an unreadable cache is compiled into like an empty one: no reason to stop
        return None
    if pending is None:
        return None
    seconds = pending.get("seconds")
    about = f"about {max(1, round(seconds))} s" if isinstance(seconds, (int, float)) else "up to about a minute"
    return f"mosd monitor: compiling kernels (first call, {about}; cached afterwards)"


def _record_first_call(fitted, seconds: float) -> None:
    """Note in the cache folder what this first call compiled (:func:`mosd.kernels.record_first_call`)."""
    from .. import kernels

    try:
        kernels.record_first_call(kernels_key(fitted), seconds)
    except Exception:  # noqa: BLE001 - the record only spares a later call the notice; the scores are written
        pass


#: how the first-alarm line names a statistic (the rest by their column name, upper case: T2S, Q, I2E, CUSUM)
STATISTIC_NAMES = {"t2": "T²", "spe": "SPE"}


def first_alarm(out, first: int) -> str:
    """The line on the first alarm: each statistic beside its limit, and the tags behind it where the model names them.

    Read from the output's columns, whatever the family: a chart's ``statistic``/``limit`` (and its subgroup),
    else every ``<name>_limit`` with the statistic it applies to, ``<name>_smoothed`` where the design smooths
    (λ < 1) else ``<name>`` (PCA's T² and SPE, CVA's T2S, T2R and Q, a per-tag chart's EWMA or CUSUM, ...),
    then every ``top_<name>`` column. Naming PCA's columns here crashed on every other family's model.
    """
    row = out.iloc[first]
    if "statistic" in out.columns:  # a chart, a threshold or a CUSUM on a stream
        where = f" (subgroup {row['subgroup']})" if "subgroup" in out.columns else ""
        return f"first alarm at row {first}{where}: statistic {row['statistic']:.4g} (limit {row['limit']:.4g})"
    columns = list(out.columns)
    shown = []
    for column in columns:
        name = column.removesuffix("_limit")
        statistic = next((c for c in (f"{name}_smoothed", name) if c in columns), None)
        if column.endswith("_limit") and statistic is not None:
            shown.append(f"{STATISTIC_NAMES.get(name, name.upper())} {row[statistic]:.4g} (limit {row[column]:.4g})")
    tops = [f"top {STATISTIC_NAMES.get(c[4:], c[4:].upper())} {row[c]}" for c in columns if c.startswith("top_")]
    return (f"first alarm at row {first}" + (": " + ", ".join(shown) if shown else "")
            + ("; " + ", ".join(tops) if tops else ""))


def read_mapping(path: str | None, option: str, keys, required: bool) -> dict | None:
    """A YAML mapping of column → node (id or browse name) from ``path``; None when not given."""
    if path is None:
        return None
    import yaml

    file = Path(path).expanduser()
    if not file.is_file():
        raise ConfigError(f"{option}={path!r}: no such file; allowed: a YAML file of column: node id or browse name")
    try:
        data = yaml.safe_load(file.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{option}={path!r} is not YAML ({' '.join(str(exc).split())[:200]}); allowed: a mapping "
                          "column: node") from None
    if not isinstance(data, dict) or not all(isinstance(v, (str, int)) for v in data.values()):
        raise ConfigError(f"{option}={path!r} is not a mapping of column: node id or browse name; allowed: lines "
                          "such as 'tag0: ns=2;s=tag0'")
    data = {str(k): str(v) for k, v in data.items()}
    allowed = ", ".join(list(keys)[:8]) + (", ..." if len(keys) > 8 else "")
    extra = [k for k in data if k not in keys]
    if extra:
        raise ConfigError(f"{option} {extra[0]!r} is not a column of the model; allowed: {allowed}")
    missing = [k for k in keys if k not in data]
    if required and missing:
        raise ConfigError(f"{option}={path!r} maps no node to the model's input {missing[0]!r} ({len(missing)} "
                          f"missing); allowed: every input ({allowed})")
    return data


def load_pipeline(model: str, tracking_uri: str | None):
    """The fitted pipeline of ``--model``: a ``pipeline.npz`` (or its directory), else an MLflow model URI."""
    from .detector_model import STATE_FILE, load_fitted

    path = Path(model).expanduser()
    if path.is_dir() and (path / STATE_FILE).is_file():
        path = path / STATE_FILE
    if path.suffix == ".npz":
        if not path.is_file():
            raise ConfigError(f"--model={model!r}: no such file; allowed: a model URI or a pipeline.npz")
        try:
            return load_fitted(path)
        except (OSError, ValueError, KeyError) as exc:
            raise ConfigError(f"--model={model!r} cannot be read ({type(exc).__name__}); allowed: a pipeline.npz "
                              "mosd wrote") from None
    tracking = tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()
    check_store(model, tracking)
    fitted = getattr(_load(model, tracking).unwrap_python_model(), "fitted", None)
    if fitted is None or not hasattr(fitted, "update"):
        raise ConfigError(f"--model={model!r} is not a mosd pipeline model; allowed: the model URI a mosd run printed")
    return fitted


def live_options(args, pipeline):
    """The checked options (one line each)."""
    from urllib.parse import urlparse

    parsed = urlparse(args.opcua)
    if parsed.scheme != "opc.tcp" or not parsed.hostname:
        raise ConfigError(f"--opcua={args.opcua!r} is not an OPC UA URL; allowed: opc.tcp://HOST:PORT[/path]")
    if parsed.username or parsed.password:
        raise ConfigError("--opcua carries a user or password; allowed: a URL without them, credentials in "
                          "MOSD_OPCUA_USER and MOSD_OPCUA_PASSWORD (docs/how-to/opcua.md)")
    if args.data is not None:
        raise ConfigError(f"DATA={args.data!r} with --opcua; allowed: one of a file and --opcua")
    if args.step is None:
        raise ConfigError("--step is required with --opcua; allowed: the model's sampling step in seconds (the "
                          "training data's time step)")
    for name, value, low in (("--step", args.step, 0.0), ("--interval", args.interval, 0.0),
                             ("--timeout", args.timeout, 0.0)):
        if value is not None and not value > low:
            raise ConfigError(f"{name}={value!r} is out of range; allowed: a number of seconds > {low:g}")
    if args.late is not None and not args.late >= 0:
        raise ConfigError(f"--late={args.late!r} is out of range; allowed: a number of seconds >= 0")
    for name, value in (("--samples", args.samples), ("--checkpoint-every", args.checkpoint_every)):
        if value is not None and value < 1:
            raise ConfigError(f"{name}={value} is out of range; allowed: integers >= 1")
    from ..live.client import LiveOptions, seconds

    inputs = tuple(pipeline.inputs)
    nodes = read_mapping(args.nodes, "--nodes", inputs, required=True) or {t: t for t in inputs}
    outputs = [c for c in pipeline.outputs if c not in pipeline.state_names]
    write = read_mapping(args.write, "--write", outputs, required=False)
    if args.out is not None and not args.out.lower().endswith(".csv"):
        raise ConfigError(f"--out={args.out!r} with --opcua: the log is a CSV file appended sample by sample; "
                          "allowed: a .csv path")
    state = check_out(args.state) if args.state is not None else None
    if state is not None and args.state == args.out:
        raise ConfigError("--state and --out name the same file; allowed: two files")
    return LiveOptions(url=args.opcua, nodes=nodes, write=write, out=check_out(args.out), state=state,
                       step=args.step, interval=args.interval,
                       since=seconds(args.since, "--since") if args.since is not None else None,
                       samples=args.samples, checkpoint_every=args.checkpoint_every, timeout=args.timeout,
                       late=args.late, security=os.environ.get("MOSD_OPCUA_SECURITY") or None,
                       user=os.environ.get("MOSD_OPCUA_USER") or None,
                       password=os.environ.get("MOSD_OPCUA_PASSWORD") or None, quiet=args.no_progress)


async def _run_live(monitor, stopping: list) -> int:
    import asyncio
    import signal

    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):  # flush the state and the log, exit 0
        loop.add_signal_handler(sig, monitor.stop.set)
    if stopping:  # a signal while the model loaded: stop at once, the state as it was
        monitor.stop.set()
    return await monitor.run()


def live_main(args) -> int:
    """``mosd monitor --opcua`` (:mod:`mosd.live.client`): the exit code (0 done or stopped; 2 a mistake to fix,
    in one line). Credentials come from the environment only (``MOSD_OPCUA_USER``, ``MOSD_OPCUA_PASSWORD``;
    ``MOSD_OPCUA_SECURITY``: asyncua's security string ``Policy,Mode,certificate,private_key``): a URL carrying
    a user or password is refused, as a command line is visible to every user of the machine (``ps``)."""
    import asyncio
    import logging
    import signal

    stopping: list = []
    for sig in (signal.SIGTERM, signal.SIGINT):  # until the loop's own handlers: noted, acted on at its start
        signal.signal(sig, lambda number, frame: stopping.append(number))
    try:
        from ..live import require_asyncua

        require_asyncua()
        from ..live.client import LiveMonitor

        # asyncua logs every reconnect attempt and server quirk as warnings: mosd says what matters in one line
        logging.getLogger("asyncua").setLevel(logging.CRITICAL)
        pipeline = load_pipeline(args.model, args.tracking_uri)
        monitor = LiveMonitor(pipeline, live_options(args, pipeline), model=args.model)
        code = asyncio.run(_run_live(monitor, stopping))
        # the loop's handlers are gone with it; the checkpoint is written: a late SIGTERM does not cut the summary
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    except ConfigError as exc:
        print(f"mosd monitor: error: {redacted(str(exc))}", file=sys.stderr)
        return 2
    t = monitor.totals
    counts = monitor.aligner.counts
    print(f"{monitor.o.url}: {t.scored} samples scored, {t.alarms} alarms; missing: {counts['bad']} bad-quality "
          f"values, {counts['absent']} absent values, {counts['missing_rows']} missing rows"
          f"{f'; {t.dropped} rows dropped (data.fill=drop)' if t.dropped else ''}; {t.history} values from history; "
          f"{t.reconnects} reconnects; {t.extra.get('write_errors', 0)} refused writes; next sample "
          f"{monitor.aligner.next_number}", flush=True)
    return code


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.opcua is not None:
        return live_main(args)
    if args.data is None:
        print("mosd monitor: error: DATA is required; allowed: a .csv or .parquet file, -, or --opcua URL",
              file=sys.stderr)
        return 2
    try:
        if args.chunk < 1:
            raise ConfigError(f"--chunk={args.chunk} is out of range; allowed: integers >= 1")
        out_path = check_out(args.out)
        tracking = args.tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()
        check_store(args.model, tracking)
        path = "stdin" if args.data == "-" else Path(args.data).expanduser()
        frame = read_data(args.data)
        frame.columns = [str(c) for c in frame.columns]
        # a run's test_stream.parquet: its time and the run's own decisions come along as run_<name>
        from .deploy import REFERENCE_ATTR

        reference = [c for c in frame.attrs.get(REFERENCE_ATTR, ()) if c in frame.columns and c not in args.keep]
        if len(set(args.keep)) != len(args.keep):
            raise ConfigError("--keep names a column twice; allowed: distinct columns")
        missing = [c for c in args.keep if c not in frame.columns]
        if missing:
            raise ConfigError(f"--keep {missing[0]!r} is not a column of {path}; allowed: {', '.join(frame.columns[:8])}")
        model = _load(args.model, tracking)
        tags = frame.drop(columns=[*args.keep, *reference])
        # MLflow's schema enforcement would drop an extra column with a warning: here it is a mistake
        names = model.metadata.get_input_schema().input_names()
        for kind, found in (("is missing", [n for n in names if n not in tags.columns]),
                            ("is not a tag of the model", [c for c in tags.columns if c not in names])):
            if found:
                raise ConfigError(f"column {found[0]!r} of {path} {kind} ({len(found)} such); allowed: the model's "
                                  f"{len(names)} tags in any order, other columns named with --keep")
        fitted = getattr(model.unwrap_python_model(), "fitted", None)
        fill = getattr(fitted, "fill", "none")
        if fill != "none":
            # the training data's policy for historian error codes and gaps (mosd.data.table), on the whole file
            import pandas as pd

            from ..data.table import MAX_ABS, _fill

            values = np.column_stack([pd.to_numeric(tags[c], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
                                      for c in tags.columns])
            values[np.abs(values) > MAX_ABS] = np.nan  # an error code such as 1e308, as the training data read it
            values, _, kept = _fill(values, np.zeros(len(values), int), fill)
            frame = frame.iloc[kept]
            tags = pd.DataFrame(values, columns=tags.columns, index=frame.index)
        progress = not args.no_progress and sys.stderr.isatty()
        # on a terminal, as the progress bar: a one-line error on stderr stays the only line where it is read
        notice, first_chunk_s = progress and announce_compile(fitted), []
        try:
            out = score_file(model, tags, args.chunk, progress=progress, first_chunk_s=first_chunk_s)
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
    if notice and first_chunk_s:
        _record_first_call(fitted, first_chunk_s[0])
    for position, column in enumerate(args.keep):  # first, in the order given
        out.insert(position, column, frame[column].to_numpy())
    for position, column in enumerate(reference, start=len(args.keep)):
        out.insert(position, column if column == "t" else f"run_{column}", frame[column].to_numpy())
    alarms = out["alarm"].to_numpy(bool)
    if "subgroup" in out.columns:  # a chart decides once per completed subgroup
        decided = int((out["subgroup"].to_numpy() > 0).sum())
        print(f"{path}: {len(out)} rows, {int(alarms.sum())} alarms in {decided} subgroups "
              f"({alarms.sum() / decided if decided else 0:.4f} of them)")
    else:
        print(f"{path}: {len(out)} rows, {int(alarms.sum())} alarms ({alarms.mean() if len(out) else 0:.4f} of rows)")
    if alarms.any():
        print(first_alarm(out, int(alarms.argmax())))
    if "alarm" in reference:
        same = int(np.sum(out["run_alarm"].to_numpy(bool) == alarms))
        print(f"the run's own alarms: {same} of {len(out)} rows agree"
              + ("" if same == len(out) else " (the model does not reproduce its run)"))
    if out_path is not None:
        from .atomic import write_atomically

        try:
            write_atomically(out_path, lambda f: out.to_csv(f, index=False))
        except OSError as exc:  # checked writable before scoring; a disk that filled up since
            print(f"mosd monitor: error: --out={args.out!r} could not be written ({exc.strerror or exc}); "
                  "nothing was written", file=sys.stderr)
            return 1
        print(f"per-row output: {args.out}")
    return 0

"""``mosd monitor --opcua URL --model URI --step S [--nodes FILE.yaml] [--write FILE.yaml] [--out log.csv]
[--state state.json]``: the command line of :mod:`mosd.live.client` (called by :mod:`mosd.app.monitor`).

Everything the user must fix is one line and exit code 2, before anything is written: a missing extra,
a bad option, a YAML file that is not a mapping of the model's columns, a model that cannot be loaded,
a server that does not answer, a tag missing from the server or not numeric. Credentials come from
the environment only (``MOSD_OPCUA_USER``, ``MOSD_OPCUA_PASSWORD``; ``MOSD_OPCUA_SECURITY``: asyncua's
security string ``Policy,Mode,certificate,private_key[,server_certificate]``): a URL carrying a
user or password is refused, as a command line is visible to every user of the machine (``ps``).
"""
from __future__ import annotations

import asyncio
import os
import signal
import sys
from pathlib import Path
from urllib.parse import urlparse

from ..validation import ConfigError
from . import require_asyncua
from .client import LiveMonitor, LiveOptions, seconds


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
    from ..app.detector_model import STATE_FILE, load_fitted

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
    from ..app.monitor import _load, check_store
    from ..app.settings import default_tracking_uri

    tracking = tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()
    check_store(model, tracking)
    fitted = getattr(_load(model, tracking).unwrap_python_model(), "fitted", None)
    if fitted is None or not hasattr(fitted, "update"):
        raise ConfigError(f"--model={model!r} is not a mosd pipeline model; allowed: the model URI a mosd run printed")
    return fitted


def options(args, pipeline) -> LiveOptions:
    """The checked options (one line each)."""
    parsed = urlparse(args.opcua)
    if parsed.scheme != "opc.tcp" or not parsed.hostname:
        raise ConfigError(f"--opcua={args.opcua!r} is not an OPC UA URL; allowed: opc.tcp://HOST:PORT[/path]")
    if parsed.username or parsed.password:
        raise ConfigError("--opcua carries a user or password; allowed: a URL without them, credentials in "
                          "MOSD_OPCUA_USER and MOSD_OPCUA_PASSWORD (docs/OPCUA.md)")
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
    from ..app.monitor import check_out

    inputs = tuple(pipeline.inputs)
    nodes = read_mapping(args.nodes, "--nodes", inputs, required=True) or {t: t for t in inputs}
    outputs = [c for c in pipeline.outputs if c not in pipeline.state_names]
    write = read_mapping(args.write, "--write", outputs, required=False)
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


async def _run(monitor: LiveMonitor) -> int:
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):  # flush the state and the log, exit 0
        loop.add_signal_handler(sig, monitor.stop.set)
    return await monitor.run()


def main(args) -> int:
    """``mosd monitor --opcua``: the exit code (0 done or stopped; 2 a mistake to fix, in one line)."""
    import logging

    try:
        require_asyncua()
        # asyncua logs every reconnect attempt and server quirk as warnings: mosd says what matters in one line
        logging.getLogger("asyncua").setLevel(logging.CRITICAL)
        pipeline = load_pipeline(args.model, args.tracking_uri)
        monitor = LiveMonitor(pipeline, options(args, pipeline), model=args.model)
        code = asyncio.run(_run(monitor))
    except ConfigError as exc:
        from ..app.settings import redacted

        print(f"mosd monitor: error: {redacted(str(exc))}", file=sys.stderr)
        return 2
    t = monitor.totals
    counts = monitor.aligner.counts
    print(f"{monitor.o.url}: {t.scored} samples scored, {t.alarms} alarms; missing: {counts['bad']} bad-quality "
          f"values, {counts['absent']} absent values, {counts['missing_rows']} missing rows; {t.dropped} rows "
          f"dropped (data.fill=drop); {t.history} values from history; {t.reconnects} reconnects; next sample "
          f"{monitor.aligner.next_number}", flush=True)
    return code

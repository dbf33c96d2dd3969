"""``python -m mosd.replay --opcua [--port P] [--speed S] FILE``: a recorded table served live over OPC UA.

A real asyncua server on 127.0.0.1 (no security: a test and demo stand-in for a plant's server) with one
Double variable per tag column, node id ``ns=<urn:mosd:replay>;s=<tag>``, browse name the tag, under the
object ``Plant``. Row ``i`` is published at wall time ``epoch + i * step / speed`` with source timestamp
``epoch + i * step`` (the data's clock: the step is the time column's median step, else ``--step``), so a
monitor aligns samples on the data's own step whatever the speed. A cell that is not a number (empty, a
historian's ``Bad``) is published with status ``BadSensorFailure`` and value 0.0: a client that used it
anyway would score a wrong zero, which the tests would see.

History: every published value is stored in the server's in-memory history (HistoryRead, raw), so a
client that was away backfills the gap (``--no-history``: none; the gap is then missing rows). A server restarted with the same ``--epoch`` first stores every
row that was due while it was down, as a historian that kept recording would hold them, then goes on
live. ``--hold`` seconds before the first row gives clients time to subscribe.

Exit: the replay stops after the last row (``--linger`` seconds later the server closes), or on
SIGTERM/SIGINT. Bad input is one line, exit 2.
"""
from __future__ import annotations

import argparse
import asyncio
import math
import signal
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Sequence

import numpy as np

from ..validation import ConfigError
from . import require_asyncua

PROG = "python -m mosd.replay"
NAMESPACE = "urn:mosd:replay"
#: columns taken as a time column when --time-column is not given
TIME_NAMES = ("time", "t", "datetime", "timestamp", "date")


@dataclass
class Recording:
    """The tag columns of a table as floats (NaN: not a number in the file), their names and the step (s)."""

    values: np.ndarray
    tags: tuple[str, ...]
    step: float


def read_recording(path: str, time_column: str | None = None, drop: Sequence[str] = (),
                   step: float | None = None) -> Recording:
    """The tag columns of a CSV/Parquet file (a ``data=table`` file, a TE export, a SKAB CSV).

    Parameters
    ----------
    path : str
        The file.
    time_column : str, optional
        Its time column (timestamps or seconds): sets the step (median difference); not a tag.
        Default: a column named time, t, datetime, timestamp or date, if there is one.
    drop : sequence of str
        Other columns that are not tags (labels).
    step : float, optional
        Seconds per row when there is no time column (default 1).
    """
    import pandas as pd

    from ..app.monitor import read_data

    try:
        frame = read_data(path)
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("DATA=", "FILE=")) from None
    if frame.shape[1] == 1 and ";" in str(frame.columns[0]):  # SKAB's files are ';'-separated
        frame = pd.read_csv(Path(path).expanduser(), sep=";")
    frame.columns = [str(c) for c in frame.columns]
    for name in drop:
        if name not in frame.columns:
            raise ConfigError(f"--drop {name!r} is not a column of {path}; allowed: {', '.join(frame.columns[:8])}")
    if time_column is not None and time_column not in frame.columns:
        raise ConfigError(f"--time-column {time_column!r} is not a column of {path}; allowed: "
                          f"{', '.join(frame.columns[:8])}")
    if time_column is None:
        time_column = next((c for c in frame.columns if c.lower() in TIME_NAMES), None)
    if step is not None and not (step > 0 and math.isfinite(step)):
        raise ConfigError(f"--step={step!r} is out of range; allowed: a number of seconds > 0")
    if time_column is not None:
        column = frame[time_column]
        seconds = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
        if np.isnan(seconds).any():
            stamps = pd.to_datetime(column, errors="coerce", utc=True)
            seconds = (stamps - stamps.iloc[0]).dt.total_seconds().to_numpy(dtype=float, na_value=np.nan)
        steps = np.diff(seconds)
        if len(steps) and not (np.isfinite(steps).all() and (steps > 0).all()):
            raise ConfigError(f"--time-column {time_column!r} of {path} does not strictly increase; allowed: a "
                              "time column in time order (or none: --step)")
        step = step or (float(np.median(steps)) if len(steps) else 1.0)
    tags = [c for c in frame.columns if c != time_column and c not in drop]
    if not tags:
        raise ConfigError(f"{path} has no tag column; allowed: a table with numeric tag columns")
    values = np.column_stack([pd.to_numeric(frame[c], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
                              for c in tags])
    empty = [t for j, t in enumerate(tags) if np.isnan(values[:, j]).all()]
    if empty:
        raise ConfigError(f"column {empty[0]!r} of {path} holds no number; allowed: numeric tag columns "
                          "(--drop the others)")
    return Recording(values=values, tags=tuple(tags), step=float(step or 1.0))


def _local_users():
    """A user manager that makes every client an administrator (the replay serves 127.0.0.1 only): it may add
    mosd's output nodes, which a plant's server would leave to its administrator (then: --write)."""
    from asyncua.crypto.permission_rules import User, UserRole
    from asyncua.server.user_managers import UserManager

    class Local(UserManager):
        def get_user(self, iserver, username=None, password=None, certificate=None):
            return User(role=UserRole.Admin, name=username)

    return Local()


class ReplayServer:
    """The asyncua server replaying a :class:`Recording` (module docstring); ``async with`` starts and stops it."""

    def __init__(self, recording: Recording, port: int = 4840, speed: float = 1.0, epoch: float | None = None,
                 history: bool = True):
        if not (speed > 0 and math.isfinite(speed)):
            raise ConfigError(f"--speed={speed!r} is out of range; allowed: a number > 0")
        if not 0 < port < 65536:
            raise ConfigError(f"--port={port} is out of range; allowed: 1..65535")
        self.recording, self.port, self.speed, self.keeps_history = recording, port, speed, history
        self.epoch = time.time() if epoch is None else float(epoch)
        self.url = f"opc.tcp://127.0.0.1:{port}/mosd/"
        #: wall time (time.time) at which row i's last tag was written, for the bench's latency
        self.published: dict[int, float] = {}
        self.next_row = 0

    async def __aenter__(self):
        asyncua = require_asyncua()
        from asyncua import ua
        from asyncua.server.history import HistoryDict

        self.ua = ua
        self.server = asyncua.Server(user_manager=_local_users())
        await self.server.init()
        self.server.set_endpoint(self.url)
        self.server.set_server_name("mosd replay")
        self.server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        # history written by the replay itself (every row, unchanged values included), not sampled by a subscription
        self.history = HistoryDict()
        self.server.iserver.history_manager.set_storage(self.history)
        self.ns = await self.server.register_namespace(NAMESPACE)
        plant = await self.server.nodes.objects.add_object(ua.NodeId("Plant", self.ns), "Plant")
        self.nodes = []
        for tag in self.recording.tags:
            node = await plant.add_variable(ua.NodeId(tag, self.ns), tag, ua.Variant(0.0, ua.VariantType.Double))
            await node.write_attribute(ua.AttributeIds.AccessLevel, ua.DataValue(ua.Variant(
                ua.AccessLevel.CurrentRead.mask | ua.AccessLevel.HistoryRead.mask, ua.VariantType.Byte)))
            await node.write_attribute(ua.AttributeIds.Historizing,
                                       ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)))
            if self.keeps_history:
                await self.history.new_historized_node(node.nodeid, None, 0)
            # no value before row 0: a client subscribing early must not take the placeholder for a sample
            await self.server.write_attribute_value(node.nodeid, ua.DataValue(
                ua.Variant(0.0, ua.VariantType.Double), StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)))
            self.nodes.append(node)
        # a variable that is no tag (text): what a node id naming a non-numeric node looks like
        await plant.add_variable(ua.NodeId("Info", self.ns), "Info", ua.Variant(
            f"mosd replay: {len(self.recording.values)} rows x {len(self.recording.tags)} tags", ua.VariantType.String))
        await self.server.start()
        return self

    async def __aexit__(self, *exc):
        await self.server.stop()

    def due(self, row: int) -> float:
        """Wall time at which ``row`` is published."""
        return self.epoch + row * self.recording.step / self.speed

    async def publish(self, row: int) -> None:
        """Write row ``row``'s values (a NaN as status BadSensorFailure) and store them in the history."""
        ua = self.ua
        stamp = datetime.fromtimestamp(self.epoch + row * self.recording.step, timezone.utc)
        now = datetime.now(timezone.utc)
        for node, value in zip(self.nodes, self.recording.values[row]):
            good = math.isfinite(value)
            dv = ua.DataValue(ua.Variant(float(value) if good else 0.0, ua.VariantType.Double),
                              StatusCode=ua.StatusCode(ua.StatusCodes.Good if good else ua.StatusCodes.BadSensorFailure),
                              SourceTimestamp=stamp, ServerTimestamp=now)
            await self.server.write_attribute_value(node.nodeid, dv)
            if self.keeps_history:
                await self.history.save_node_value(node.nodeid, dv)
        self.published[row] = time.time()

    async def replay(self, stop: asyncio.Event | None = None) -> int:
        """Publish every row at its due time (rows already due at once, into the history); the rows published."""
        stop = stop or asyncio.Event()
        rows = len(self.recording.values)
        while self.next_row < rows and not stop.is_set():
            wait = self.due(self.next_row) - time.time()
            if wait > 0:
                try:
                    await asyncio.wait_for(stop.wait(), wait)
                    break
                except asyncio.TimeoutError:
                    pass
            await self.publish(self.next_row)
            self.next_row += 1
            await asyncio.sleep(0)  # a replay behind its schedule still lets the server publish between rows
        return self.next_row


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse prints the usage first)
        print(f"mosd replay: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Replay a recorded table as a live OPC UA server on 127.0.0.1.")
    p.add_argument("file", help="a .csv or .parquet table: one row per sample (a data=table file, a TE export, a "
                   "SKAB CSV)")
    p.add_argument("--opcua", action="store_true", required=True, help="serve over OPC UA (the only protocol)")
    p.add_argument("--port", type=int, default=4840, help="TCP port on 127.0.0.1 (default 4840)")
    p.add_argument("--speed", type=float, default=1.0, help="rows per data step of wall time (default 1: real time)")
    p.add_argument("--time-column", default=None, help="the time column (default: one named time, t, datetime, "
                   "timestamp or date)")
    p.add_argument("--drop", action="append", default=[], metavar="COLUMN", help="a column that is not a tag (a "
                   "label; repeatable)")
    p.add_argument("--step", type=float, default=None, help="seconds per row without a time column (default 1)")
    p.add_argument("--epoch", type=float, default=None, help="wall time (Unix seconds) of row 0 (default: now + "
                   "--hold); a server restarted with the same epoch holds the rows due meanwhile in its history")
    p.add_argument("--hold", type=float, default=0.0, help="seconds before row 0 is published (default 0)")
    p.add_argument("--no-history", action="store_true", help="keep no history (a server without HistoryRead: a "
                   "client's gap is missing rows)")
    p.add_argument("--linger", type=float, default=3600.0, help="seconds the server stays up after the last row")
    return p


async def _serve(args) -> int:
    recording = read_recording(args.file, args.time_column, args.drop, args.step)
    epoch = args.epoch if args.epoch is not None else time.time() + max(args.hold, 0.0)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    try:
        server = ReplayServer(recording, args.port, args.speed, epoch, history=not args.no_history)
        async with server:
            print(f"replaying {len(recording.values)} rows x {len(recording.tags)} tags of {args.file} at "
                  f"{server.url} (step {recording.step:g} s, speed {args.speed:g}, epoch {epoch:.3f})", flush=True)
            published = await server.replay(stop)
            if not stop.is_set():
                print(f"replay done: {published} rows", flush=True)
                try:
                    await asyncio.wait_for(stop.wait(), max(args.linger, 0.0))
                except asyncio.TimeoutError:
                    pass
    except OSError as exc:
        raise ConfigError(f"--port={args.port}: cannot serve on 127.0.0.1 ({exc.strerror or exc}); allowed: a free "
                          "port") from None
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    import logging

    args = parser().parse_args(argv)
    logging.getLogger("asyncua").setLevel(logging.ERROR)  # its per-connection info lines are not the user's
    try:
        return asyncio.run(_serve(args))
    except ConfigError as exc:
        print(f"mosd replay: error: {exc}", file=sys.stderr)
        return 2

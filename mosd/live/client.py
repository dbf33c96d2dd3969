"""``mosd monitor --opcua URL``: a fitted pipeline scoring a live OPC UA server, sample by sample.

The loop (:class:`LiveMonitor`): connect; resolve the model's input columns to nodes (``--nodes``: node
ids or browse names) and check each is a numeric variable; subscribe to every tag (data-change trigger
status-value-timestamp, so a repeated value with a new timestamp is a new sample); read the server's
history from the first sample not yet scored (a restart, a reconnect: the gap is backfilled in order
when the server has history, else its samples come out missing); then for each aligned sample
(:mod:`mosd.live.align`) the pipeline's one-step update with the carried state
(:meth:`mosd.streaming.OnlinePipeline.update`: whole, in chunks or row by row, the same alarms), the
outputs written back to OPC UA nodes (created by mosd under ``Objects/mosd``, or named by ``--write``)
and appended to the CSV log ``--out``.

State survives (:class:`Checkpoint`): every ``--checkpoint-every`` samples and at exit the pipeline's
state, the first sample not yet scored, the gap policy's waiting rows and the log's length are written
atomically to ``--state``. Restarted with the same file, the monitor cuts the log back to that length
and goes on from that sample: after a SIGKILL the samples since the checkpoint are scored again, once,
from the same state, and the log ends as an uninterrupted run's. SIGTERM/SIGINT checkpoint, flush
and exit 0. A connection lost later is retried with back-off; the first connection failing is the
user's to fix (one line, exit 2), as are a tag missing from the server or of a non-numeric type.
"""
from __future__ import annotations

import asyncio
import math
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Mapping

import numpy as np

from ..validation import ConfigError
from .align import Aligner, CausalFill, Sample

#: OPC UA built-in data types (ns=0 ids) a tag may have: Boolean, SByte..UInt64, Float, Double
NUMERIC_TYPES = {1: "Boolean", 2: "SByte", 3: "Byte", 4: "Int16", 5: "UInt16", 6: "Int32", 7: "UInt32",
                 8: "Int64", 9: "UInt64", 10: "Float", 11: "Double"}
#: a node id written as text (ns=2;s=x, i=85, nsu=urn:...;s=x); anything else is a browse name
NODE_ID = re.compile(r"^(ns=\d+;|nsu=[^;]+;)?[isgb]=")
#: the namespace of the nodes mosd creates for its outputs
OUTPUT_NAMESPACE = "urn:mosd:monitor"
STATE_FORMAT = 1
#: the default publishing interval, s: the model's step, at most this (an alarm waits for the next publish)
MAX_INTERVAL = 1.0


@dataclass
class LiveOptions:
    """What ``mosd monitor --opcua`` was asked (see :func:`mosd.app.monitor.parser`)."""

    url: str
    nodes: Mapping[str, str]
    write: Mapping[str, str] | None = None
    out: Path | None = None
    state: Path | None = None
    step: float = 1.0
    interval: float | None = None
    since: float | None = None
    samples: int | None = None
    checkpoint_every: int = 100
    timeout: float = 10.0
    late: float | None = None
    max_backoff: float = 10.0
    security: str | None = None
    user: str | None = None
    password: str | None = None
    quiet: bool = False


@dataclass
class Totals:
    """What a run did, carried across restarts in the checkpoint."""

    scored: int = 0
    alarms: int = 0
    dropped: int = 0
    history: int = 0
    reconnects: int = 0
    extra: dict = field(default_factory=dict)


def node_id_or_name(spec: str):
    """A ``--nodes`` entry as a NodeId, or None when it is a browse name."""
    from asyncua import ua

    return ua.NodeId.from_string(spec) if NODE_ID.match(spec) else None


class LiveMonitor:
    """The loop of the module docstring for one pipeline and one server."""

    def __init__(self, pipeline, options: LiveOptions, model: str = ""):
        self.pipeline, self.o, self.model = pipeline, options, model
        self.inputs = tuple(pipeline.inputs)
        self.state_names = tuple(pipeline.state_names)
        self.state = pipeline.initial_state()
        self.interval = options.interval if options.interval is not None else min(options.step, MAX_INTERVAL)
        self.late = options.late if options.late is not None else 1.0 + 2 * self.interval
        self.aligner = Aligner(len(self.inputs), options.step, t_ref=options.since, late=self.late)
        self.fill = CausalFill(pipeline.fill, len(self.inputs))
        self.totals = Totals()
        self.queue: asyncio.Queue = asyncio.Queue()
        self.stop = asyncio.Event()
        self.log_bytes = 0
        self.columns: list[str] | None = None
        self.since_checkpoint = 0
        self.write_nodes: list = []
        self.write_columns: list[str] = []
        self.tag_nodes: list = []
        self.index: dict = {}
        self.on_written = None  # the bench's hook: called with the written samples' numbers

    # -- state -----------------------------------------------------------------------------
    def load_checkpoint(self) -> None:
        """Continue from ``--state`` when it exists (one line when it belongs to another model or step)."""
        import json

        path = self.o.state
        if path is None or not path.exists():
            if self.o.out is not None:
                self.o.out.write_text("")  # a fresh run starts a fresh log
            return
        try:
            data = json.loads(path.read_text())
            ok = data.get("format") == STATE_FORMAT
        except (OSError, ValueError) as exc:
            raise ConfigError(f"--state={str(path)!r} cannot be read ({exc}); allowed: a state file mosd monitor "
                              "--opcua wrote") from None
        if not ok or list(data.get("inputs", ())) != list(self.inputs):
            raise ConfigError(f"--state={str(path)!r} is not a state of this model (its inputs differ); allowed: "
                              "the state file of the same model, or a new path")
        if data["step"] != self.o.step:
            raise ConfigError(f"--step={self.o.step:g} differs from the state's {data['step']:g} s; allowed: "
                              f"--step {data['step']:g} with --state {path}")
        self.state = self.pipeline.check_state(data["state"])
        self.aligner = Aligner(len(self.inputs), self.o.step, t_ref=data["t_ref"], next_number=data["next_number"],
                               late=self.late, counts=dict(data["counts"]))
        self.fill.load_json(data["fill"])
        self.totals = Totals(**data["totals"])
        self.log_bytes = int(data.get("log_bytes", 0))
        self.columns = data.get("columns")
        if self.o.out is not None:
            size = self.o.out.stat().st_size if self.o.out.exists() else 0
            if size < self.log_bytes:
                raise ConfigError(f"--out={str(self.o.out)!r} has {size} bytes, the state says {self.log_bytes}: it "
                                  "is not this state's log; allowed: the log written with this --state")
            with open(self.o.out, "r+b") as f:  # what was logged after the checkpoint is scored again
                f.truncate(self.log_bytes)

    def save_checkpoint(self) -> None:
        import json

        from ..app.atomic import write_atomically

        self.since_checkpoint = 0
        if self.o.state is None:
            return
        state = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.state.items()}
        data = {"format": STATE_FORMAT, "model": self.model, "inputs": list(self.inputs), "step": self.o.step,
                "state": state, "fill": self.fill.to_json(), "totals": self.totals.__dict__,
                "log_bytes": self.log_bytes, "columns": self.columns, **self.aligner.to_json()}
        write_atomically(self.o.state, lambda f: json.dump(data, f, allow_nan=False))

    # -- scoring ---------------------------------------------------------------------------
    def score(self, rows: list[tuple[Sample, bool]]) -> dict | None:
        """The pipeline's update of the kept rows from the carried state; log them; the outputs."""
        self.totals.dropped += sum(not kept for _, kept in rows)
        kept = [s for s, k in rows if k]
        if not kept:
            return None
        X = np.vstack([s.values for s in kept])
        with np.errstate(over="ignore", invalid="ignore"):  # as the served model: an overflowing row is not scored
            out = self.pipeline.update({name: X[:, j] for j, name in enumerate(self.inputs)}, self.state)
        self.state = self.pipeline.final_state(out, self.state)
        self.totals.scored += len(kept)
        self.totals.alarms += int(np.asarray(out["alarm"], bool).sum())
        self.since_checkpoint += len(kept)
        self.append_log(kept, out)
        return {"samples": kept, "out": out}

    def append_log(self, samples: list[Sample], out: dict) -> None:
        if self.o.out is None:
            return
        import pandas as pd

        frame = pd.DataFrame({"time": [_iso(s.time) for s in samples], "sample": [s.number for s in samples],
                              "missing": [s.bad + s.absent for s in samples], **out})
        header = self.columns is None
        self.columns = list(frame.columns)
        with open(self.o.out, "a", encoding="utf-8", newline="") as f:
            frame.to_csv(f, index=False, header=header)
            f.flush()
            self.log_bytes = f.tell()

    async def process(self, client, final: bool = False) -> None:
        """Hand the samples that may leave to the gap policy, score, write back, checkpoint."""
        upto = self.o.samples
        rows = []
        for sample in self.aligner.close(upto):
            rows += self.fill.push(sample)
        if final or (upto is not None and self.aligner.next_number >= upto):
            rows += self.fill.flush()
        scored = self.score(rows)
        if scored is not None and client is not None:
            await self.write_back(client, scored)
        if self.since_checkpoint >= self.o.checkpoint_every:
            self.save_checkpoint()
        if upto is not None and self.aligner.next_number >= upto and not self.fill.pending:
            self.stop.set()

    async def write_back(self, client, scored: dict) -> None:
        from asyncua import ua

        nodes, values = [], []
        out = scored["out"]
        for i, sample in enumerate(scored["samples"]):
            stamp = datetime.fromtimestamp(sample.time, timezone.utc)
            for node, column, kind in zip(self.write_nodes, self.write_columns, self.write_kinds):
                nodes.append(node)
                values.append(ua.DataValue(ua.Variant(_as(out[column][i], kind), kind), SourceTimestamp=stamp))
        if nodes:
            try:
                await client.write_values(nodes, values)
            except ua.UaStatusCodeError as exc:  # refused (not writable, wrong type): counted, scoring goes on
                errors = self.totals.extra.get("write_errors", 0)
                self.totals.extra["write_errors"] = errors + 1
                if not errors:
                    self.say(f"the server refused mosd's write of the outputs ({_reason(exc)}); scoring goes on, "
                             "the log has every sample")
        if self.on_written is not None:
            self.on_written([s.number for s in scored["samples"]])

    # -- OPC UA ----------------------------------------------------------------------------
    async def connect(self):
        from asyncua import Client

        client = Client(self.o.url, timeout=self.o.timeout)
        if self.o.security:
            await client.set_security_string(self.o.security)
        if self.o.user:
            client.set_user(self.o.user)
            client.set_password(self.o.password or "")
        await asyncio.wait_for(client.connect(), self.o.timeout)
        return client

    async def resolve(self, client) -> None:
        """Tag nodes (checked numeric) and the output nodes (created under Objects/mosd, or ``--write``'s)."""
        names = await self._browse_names(client) if any(node_id_or_name(s) is None for s in self.o.nodes.values()) \
            else {}
        self.tag_nodes = [await self._node(client, tag, self.o.nodes[tag], names, "--nodes") for tag in self.inputs]
        for tag, node in zip(self.inputs, self.tag_nodes):
            kind = await node.read_data_type()
            if kind.NamespaceIndex != 0 or kind.Identifier not in NUMERIC_TYPES:
                shown = await _type_name(client, kind)
                raise ConfigError(f"--nodes {tag}: node {node.nodeid.to_string()} has data type {shown}; allowed: "
                                  f"a numeric variable ({', '.join(NUMERIC_TYPES.values())})")
        self.index = {node.nodeid: j for j, node in enumerate(self.tag_nodes)}
        kinds = self._output_kinds()
        if self.o.write is None:
            self.write_columns = list(kinds)
            self.write_nodes = await self._create_outputs(client, kinds)
        else:
            self.write_columns = list(self.o.write)
            self.write_nodes = [await self._node(client, c, self.o.write[c], names or await self._browse_names(client),
                                                 "--write") for c in self.write_columns]
        self.write_kinds = [kinds[c] for c in self.write_columns]

    def _output_kinds(self) -> dict:
        """The outputs written back (every shown output, not the state) and their OPC UA types."""
        from asyncua import ua

        out = self.pipeline.predict_frame(self.pipeline.example())
        kinds = {}
        for column in self.pipeline.outputs:
            if column in self.state_names:
                continue
            kind = out[column].dtype.kind
            kinds[column] = {"b": ua.VariantType.Boolean, "i": ua.VariantType.Int64, "u": ua.VariantType.Int64,
                             "f": ua.VariantType.Double}.get(kind, ua.VariantType.String)
        if self.o.write is not None:
            unknown = [c for c in self.o.write if c not in kinds]
            if unknown:
                raise ConfigError(f"--write {unknown[0]!r} is not an output of the model; allowed: "
                                  f"{', '.join(kinds)}")
        return kinds

    async def _create_outputs(self, client, kinds: dict) -> list:
        from asyncua import ua

        try:
            ns = await client.register_namespace(OUTPUT_NAMESPACE)
            folder_id = ua.NodeId("mosd", ns)
            folder = client.get_node(folder_id)
            if not await _exists(folder):
                folder = await client.nodes.objects.add_folder(folder_id, "mosd")
            nodes = []
            for column, kind in kinds.items():
                node_id = ua.NodeId(f"mosd.{column}", ns)
                node = client.get_node(node_id)
                if not await _exists(node):
                    node = await folder.add_variable(node_id, column, ua.Variant(_as(0, kind), kind))
                # each time: a connection lost between the creation and this left the node read-only
                await node.set_writable()
                nodes.append(node)
            return nodes
        except ua.UaError as exc:
            raise ConfigError(f"the server refused to create mosd's output nodes ({exc}); allowed: --write FILE.yaml "
                              "naming existing writable nodes for the outputs") from None

    async def _browse_names(self, client, depth: int = 6, limit: int = 20000) -> dict:
        """Browse name → node ids of every variable under Objects (the Server object left out)."""
        from asyncua import ua

        found: dict[str, list] = {}
        frontier, seen = [client.nodes.objects], 0
        for _ in range(depth):
            children = []
            for node in frontier:
                if node.nodeid == ua.NodeId(ua.ObjectIds.Server):
                    continue
                for child in await node.get_children():
                    seen += 1
                    if seen > limit:
                        return found
                    name = await child.read_browse_name()
                    if await child.read_node_class() == ua.NodeClass.Variable:
                        found.setdefault(name.Name, []).append(child)
                        found.setdefault(name.to_string(), []).append(child)
                    else:
                        children.append(child)
            frontier = children
        return found

    async def _node(self, client, column: str, spec: str, names: dict, option: str):
        from asyncua import ua

        node_id = node_id_or_name(spec)
        if node_id is None:
            candidates = names.get(spec, [])
            if len(candidates) != 1:
                what = "matches no variable" if not candidates else f"matches {len(candidates)} variables"
                raise ConfigError(f"{option} {column}: browse name {spec!r} {what} on {self.o.url}; allowed: a "
                                  "unique browse name or a node id (ns=2;s=...)")
            return candidates[0]
        node = client.get_node(node_id)
        try:
            node_class = await node.read_node_class()
        except ua.UaError:
            node_class = None
        if node_class != ua.NodeClass.Variable:
            raise ConfigError(f"{option} {column}: node {spec} is not a variable on {self.o.url}; allowed: node ids "
                              "of variables the server has")
        return node

    async def subscribe(self, client):
        from asyncua import ua

        period = 1000.0 * self.interval
        monitor = self

        class Handler:
            def datachange_notification(self, node, val, data):
                monitor.queue.put_nowait((monitor.index.get(node.nodeid), data.monitored_item.Value))

        subscription = await client.create_subscription(period, Handler())
        trigger = ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.StatusValueTimestamp)
        requests = []
        for j, node in enumerate(self.tag_nodes):
            item = ua.MonitoredItemCreateRequest()
            item.ItemToMonitor = ua.ReadValueId(NodeId=node.nodeid, AttributeId=ua.AttributeIds.Value)
            item.MonitoringMode = ua.MonitoringMode.Reporting
            # a queue for every sample of a publishing interval, and a late publish (a replay faster than real
            # time, a loaded machine): none is dropped between two
            queue = int(min(10000, max(1000, 4 * period / 1000.0 / max(self.o.step, 1e-3))))
            item.RequestedParameters = ua.MonitoringParameters(ClientHandle=1000 + j, SamplingInterval=0.0,
                                                               Filter=trigger, QueueSize=queue, DiscardOldest=False)
            requests.append(item)
        results = await subscription.create_monitored_items(requests)
        bad = [(tag, r) for tag, r in zip(self.inputs, results) if isinstance(r, ua.StatusCode)]
        if bad:
            raise ConfigError(f"--nodes {bad[0][0]}: the server refused to monitor it ({bad[0][1].name}); allowed: "
                              "variables the server lets a client subscribe to")
        return subscription

    async def backfill(self, client) -> None:
        """Every tag's history from the first sample not yet scored (nothing when the server keeps none)."""
        from asyncua import ua

        if self.aligner.t_ref is None:
            return
        start = datetime.fromtimestamp(self.aligner.time_of(self.aligner.next_number) - self.o.step / 2, timezone.utc)
        for j, node in enumerate(self.tag_nodes):
            try:
                values = await node.read_raw_history(starttime=start, return_bounds=False)
            except (ua.UaError, asyncio.TimeoutError):
                self.totals.extra["no_history"] = self.totals.extra.get("no_history", 0) + 1
                return
            for dv in values:
                self._add(j, dv)
            self.totals.history += len(values)

    def _add(self, tag, dv) -> None:
        if tag is None or dv.SourceTimestamp is None:
            return
        code = dv.StatusCode.value if dv.StatusCode is not None else 0
        if self.aligner.t_ref is None and code != 0:  # "waiting for initial data" sets no clock
            return
        value = dv.Value.Value if dv.Value is not None else None
        self.aligner.add(tag, dv.SourceTimestamp.timestamp(), value, code == 0)

    def drain(self) -> None:
        """Every notification that has arrived, into the aligner."""
        while not self.queue.empty():
            self._add(*self.queue.get_nowait())

    async def consume(self, client) -> None:
        """Samples from the subscription until stopped; raises when the server is lost."""
        while not self.stop.is_set():
            try:
                first = await asyncio.wait_for(self.queue.get(), timeout=1.0)
            except asyncio.TimeoutError:
                # quiet for a second: is the server still there? (raises on a lost connection)
                await asyncio.wait_for(client.nodes.server_state.read_value(), self.o.timeout)
                continue
            self._add(*first)
            self.drain()
            await self.process(client)

    async def run(self) -> int:
        """Connect, score until stopped (or ``--samples``), checkpoint; the exit code."""
        from asyncua import ua

        self.load_checkpoint()
        delay, ready, client = 0.2, False, None
        while not self.stop.is_set():
            try:
                client = await self.connect()
                try:
                    # each time: a restarted server may have other namespace indices, and lost mosd's nodes
                    await self.resolve(client)
                except ConfigError as exc:
                    if not ready:
                        raise
                    raise ConnectionError(str(exc)) from None  # a server still starting up: retried
                ready = True
                await self.subscribe(client)
                await self.backfill(client)
                self.drain()
                await self.process(client)
                delay = 0.2
                await self.consume(client)
            except ConfigError:
                raise
            except (OSError, asyncio.TimeoutError, ua.UaError, ConnectionError) as exc:
                if not ready and isinstance(exc, ua.UaError):  # it answered: a security policy, a user refused
                    raise ConfigError(f"{self.o.url} refused the connection ({_reason(exc)}); allowed: the security "
                                      "policy and user the server accepts, in MOSD_OPCUA_SECURITY, MOSD_OPCUA_USER "
                                      "and MOSD_OPCUA_PASSWORD (docs/how-to/opcua.md)") from None
                if not ready:
                    raise ConfigError(f"{self.o.url} did not answer ({_reason(exc)}, timeout {self.o.timeout:g} s); "
                                      "allowed: the opc.tcp:// URL of a running OPC UA server") from None
                self.totals.reconnects += 1
                self.say(f"connection to {self.o.url} lost ({_reason(exc)}); reconnecting in {delay:.1f} s")
                try:
                    await asyncio.wait_for(self.stop.wait(), delay)
                except asyncio.TimeoutError:
                    pass
                delay = min(2 * delay, self.o.max_backoff)
            finally:
                if client is not None:
                    await _quietly(self.finish_and_disconnect(client))
                    client = None
        return 0

    async def finish_and_disconnect(self, client) -> None:
        if self.stop.is_set():
            await self.process(client)  # what has arrived and may leave
            self.save_checkpoint()
        await client.disconnect()

    def say(self, line: str) -> None:
        if not self.o.quiet:
            print(line, flush=True)


async def _exists(node) -> bool:
    from asyncua import ua

    try:
        await node.read_node_class()
        return True
    except ua.UaError:
        return False


async def _type_name(client, kind) -> str:
    try:
        return (await client.get_node(kind).read_browse_name()).Name
    except Exception:  # the name is only for the message
        return kind.to_string()


async def _quietly(coroutine) -> None:
    try:
        await asyncio.wait_for(coroutine, 5.0)
    except Exception:  # a lost connection cannot be closed cleanly; the checkpoint is written first
        pass


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return type(exc).__name__ + (f": {text[:200]}" if text else "")


def _iso(t: float) -> str:
    return datetime.fromtimestamp(t, timezone.utc).isoformat(timespec="milliseconds")


def _as(value, kind):
    """A model output as the Python value of an OPC UA variant type."""
    from asyncua import ua

    if kind == ua.VariantType.Boolean:
        return bool(value)
    if kind == ua.VariantType.Int64:
        return int(value)
    if kind == ua.VariantType.Double:
        return float(value)
    return str(value)


def seconds(text: str, option: str) -> float:
    """``--since`` as Unix seconds: a number, or an ISO-8601 time (UTC unless it says otherwise)."""
    try:
        return float(text)
    except ValueError:
        pass
    try:
        stamp = datetime.fromisoformat(text)
    except ValueError:
        raise ConfigError(f"{option}={text!r} is not a time; allowed: Unix seconds or ISO-8601 "
                          "(2026-01-01T00:00:00Z)") from None
    return (stamp if stamp.tzinfo else stamp.replace(tzinfo=timezone.utc)).timestamp()


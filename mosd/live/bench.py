"""Latency and load of ``mosd monitor --opcua`` against the replay server, on this machine (``python -m
mosd.bench --only opcua``).

The replay server (:class:`mosd.live.replay.ReplayServer`) runs in this process; the monitor is a separate
``python -m mosd monitor --opcua`` process, as it would be beside a plant's server, scoring a PCA pipeline
fitted on 100 correlated synthetic tags (T², SPE, top contributors). The server notes the wall time at
which each row's last tag was written, and the time each write of the monitor's ``alarm`` node arrives
(its post-write callback); the alarm's source timestamp names the row.

* latency: rows at 1 Hz × 100 tags, publishing interval 2 ms (:data:`LATENCY_INTERVAL`); the rows written
  before the monitor's first alarm write (its start-up, its backfill) are left out; p50 and p99 in ms;
* load: rows published as fast as the server can write them (100 tags each); tag-samples per second from
  the first row's write to the last row's alarm write, the monitor keeping up with everything the server
  wrote (none missing: checked).
"""
from __future__ import annotations

import asyncio
import os
import socket
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TAGS = 100
#: the latency run's publishing interval, s: the server sends a change at most this long after it (a plant's
#: server may revise it upwards, to its own minimum: the latency grows with it)
LATENCY_INTERVAL = 0.002


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pipeline(directory: Path, rng: np.random.Generator):
    """A PCA pipeline on 100 tags (5 latent factors), saved; (path, test rows with a shift on tags 0-4)."""
    from ..detectors.pca import PCADetector
    from ..monitors.outputs import OutputMonitor
    from ..streaming import OnlinePipeline

    tags = tuple(f"tag{i:03d}" for i in range(TAGS))
    mixing = rng.normal(size=(5, TAGS))

    def rows(n):
        return rng.normal(size=(n, 5)) @ mixing + 0.3 * rng.normal(size=(n, TAGS))

    calibration = np.stack([rows(600), rows(600)])
    detector = PCADetector(fit_runs=1, max_components=10, n_components=5, alpha=0.01)
    pipeline = OnlinePipeline([OutputMonitor(burn_in=0).online(tags), detector.online(calibration, tags)])
    test = rows(4000)
    test[::7, :5] += 3.0  # some alarms to write
    return pipeline.save(directory), tags, test


async def _run(npz: Path, tags, values: np.ndarray, speed: float, interval: float, hold: float) -> dict:
    """One replay of ``values`` monitored by a subprocess; per row: written at, alarm written at."""
    from asyncua.common.callback import CallbackType

    from .replay import Recording, ReplayServer

    recording = Recording(values=values, tags=tags, step=1.0)
    epoch = time.time() + hold
    alarms: dict[float, float] = {}
    async with ReplayServer(recording, port=_free_port(), speed=speed, epoch=epoch) as server:
        def written(event, dispatcher):
            now = time.time()
            for item in event.request_params.NodesToWrite:
                if item.NodeId.Identifier == "mosd.alarm" and item.Value.SourceTimestamp is not None:
                    alarms.setdefault(item.Value.SourceTimestamp.timestamp(), now)

        server.server.subscribe_server_callback(CallbackType.PostWrite, written)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            p for p in (str(Path(__file__).resolve().parents[2]), os.environ.get("PYTHONPATH")) if p))
        monitor = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "mosd", "monitor", "--opcua", server.url, "--model", str(npz), "--step", "1",
            "--interval", str(interval), "--since", repr(epoch), "--samples", str(len(values)), "--no-progress",
            "--checkpoint-every", "1000000", env=env, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
        replay = asyncio.create_task(server.replay())
        out, err = await monitor.communicate()
        await replay
        if monitor.returncode != 0:
            raise RuntimeError(f"the monitor failed: {err.decode()[-300:]}")
    rows = np.arange(len(values))
    stamps = epoch + rows * recording.step
    return {"published": np.array([server.published[i] for i in rows]),
            "alarm": np.array([alarms.get(round(float(t), 6), alarms.get(float(t), np.nan)) for t in stamps]),
            "summary": out.decode().strip().splitlines()[-1] if out else ""}


def _latency(run: dict) -> np.ndarray:
    """Per row, ms from its last tag's write to its alarm's write; rows before the monitor went live left out."""
    published, alarm = run["published"], run["alarm"]
    live = published > np.nanmin(alarm)
    return 1000.0 * (alarm[live] - published[live])


def _missing(summary: str) -> int:
    """Bad-quality and absent values and missing rows the monitor's summary line counts (-1: no such line)."""
    import re

    found = re.search(r"(\d+) bad-quality values, (\d+) absent values, (\d+) missing rows", summary)
    return sum(int(g) for g in found.groups()) if found else -1


def opcua_bench(quick: bool = False, seed: int = 0) -> dict:
    """``opcua_latency_ms_p50``, ``opcua_latency_ms_p99`` (1 Hz × 100 tags), ``opcua_samples_per_s`` (tag-samples
    per second, sustained) and what they were measured on (rows, missing alarm writes, load average)."""
    from . import require_asyncua

    import logging

    require_asyncua()
    rng = np.random.default_rng(seed)
    # the in-process server's warnings (no security on 127.0.0.1) are not the bench's table
    logging.getLogger("asyncua").setLevel(logging.ERROR)
    with tempfile.TemporaryDirectory() as tmp:
        npz, tags, test = _pipeline(Path(tmp), rng)
        latency_rows, load_rows = (15, 400) if quick else (40, 3000)
        slow = asyncio.run(_run(npz, tags, test[:latency_rows], speed=1.0, interval=LATENCY_INTERVAL, hold=8.0))
        fast = asyncio.run(_run(npz, tags, test[:load_rows], speed=1e6, interval=0.05, hold=8.0))
    ms = _latency(slow)
    first = fast["published"][0]
    last = fast["alarm"][-1]
    return {"opcua_latency_ms_p50": float(np.percentile(ms, 50)) if len(ms) else float("nan"),
            "opcua_latency_ms_p99": float(np.percentile(ms, 99)) if len(ms) else float("nan"),
            "opcua_latency_rows": int(len(ms)),
            "opcua_samples_per_s": float(load_rows * TAGS / (last - first)) if last > first else float("nan"),
            "opcua_load_rows": load_rows,
            # the replay's own pace in the load run: when it is near opcua_samples_per_s, the server is the bound
            "opcua_server_samples_per_s": float((load_rows - 1) * TAGS / (fast["published"][-1] - first)),
            "opcua_alarm_writes_missing": int(np.isnan(slow["alarm"]).sum() + np.isnan(fast["alarm"]).sum()),
            "opcua_values_missing": _missing(slow["summary"]) + _missing(fast["summary"]),
            "opcua_load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")}


if __name__ == "__main__":
    import json

    print(json.dumps(opcua_bench("--quick" in sys.argv)))

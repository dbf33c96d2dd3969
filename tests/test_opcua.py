"""``mosd monitor --opcua`` against the replay server, a real asyncua server on 127.0.0.1 (issue 52).

* a tuned model (the tiny ``data=table`` run of tests/test_detector_model.py, shared) monitoring a replay of its
  test rows writes the alarms ``mosd monitor`` writes on the file, and its outputs back to OPC UA nodes;
* a monitor SIGKILLed and restarted with the same ``--state``, and a server SIGKILLed and restarted
  mid-stream (its history holds the rows due meanwhile), each end with the uninterrupted run's log;
  bad-quality values (``Bad`` cells, served as BadSensorFailure with value 0) are counted and filled
  by the model's gap policy (hold), never used;
* a node missing from the server, a non-numeric node, a server that never answers, a missing extra:
  one line, exit code 2.
"""
from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("asyncua", reason="the opcua extra: pip install 'mosd[opcua]'")  # the test extra has it

from mosd.app.detector_model import load_fitted  # noqa: E402
from mosd.data.table import _fill  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_detector_model import PACKAGE_PARENT, TAGS, _mosd, build_logged_run, plant_table  # noqa: E402

#: replay speed: a 60 s step every 20 ms
SPEED = 3000
ROWS = 300


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env():
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    return env


@contextlib.contextmanager
def replay_server(path, port=None, epoch=None, speed=SPEED, extra=()):
    """``python -m mosd.replay --opcua`` on ``path``: yields (url, epoch, process); SIGTERM at the end."""
    port = port or free_port()
    epoch = time.time() + 4 if epoch is None else epoch
    process = subprocess.Popen([sys.executable, "-m", "mosd.replay", "--opcua", "--port", str(port), "--speed",
                                str(speed), "--epoch", repr(epoch), *extra, str(path)], env=_env(), stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    line = process.stdout.readline()  # the server listens once it prints
    assert "replaying" in line, line + process.stdout.read()[-2000:]
    threading.Thread(target=process.stdout.read, daemon=True).start()
    try:
        yield f"opc.tcp://127.0.0.1:{port}/mosd/", epoch, process
    finally:
        if process.poll() is None:
            process.terminate()
            process.wait(10)


def monitor(args, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "mosd", "monitor", *map(str, args)], env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


def live_args(url, model, tmp, name, epoch, step=60):
    return ["--opcua", url, "--model", model, "--step", step, "--interval", 0.05, "--samples", ROWS,
            "--since", repr(epoch), "--out", tmp / f"{name}.csv", "--state", tmp / f"{name}.json",
            "--checkpoint-every", 20, "--no-progress"]


@pytest.fixture(scope="module")
def tuned(tmp_path_factory, shared_build):
    """The tiny tuned run (tests/test_detector_model.py's, trained once per session): its model URI, store,
    pipeline.npz, and in this module's own folder the test rows (CSV) and the same rows with Bad cells."""
    built = shared_build("pca-table-run", build_logged_run)
    tmp = tmp_path_factory.mktemp("opcua")
    outputs = built / "out"
    uri = re.search(r"model (models:/\S+) ", (built / "stdout.txt").read_text()).group(1)
    test = plant_table().iloc[900:].drop(columns=["fault"]).reset_index(drop=True)
    test.to_csv(tmp / "test.csv", index=False)
    coded = test.astype(object)
    rng = np.random.default_rng(0)
    cells = [(int(r), int(c)) for r, c in zip(rng.integers(1, ROWS, 12), rng.integers(1, 7, 12))]
    for r, c in cells:
        coded.iloc[r, c] = "Bad"
    coded.to_csv(tmp / "coded.csv", index=False)
    npz = next(outputs.glob("runs/*/model/pipeline.npz"))
    return dict(tmp=tmp, uri=uri, tracking=f"sqlite:///{outputs / 'mlflow.db'}", outputs=outputs, npz=npz, test=test,
                coded=coded, bad=len(set(cells)))


@pytest.fixture(scope="module")
def served(tuned):
    """One replay of the test rows for the tests that need no restart: (url, epoch)."""
    with replay_server(tuned["tmp"] / "test.csv") as (url, epoch, _):
        yield url, epoch


def expected(pipeline, frame):
    """The uninterrupted run: the model's gap policy on the whole table, then one update from the start."""
    import pandas as pd

    values = np.column_stack([pd.to_numeric(frame[t], errors="coerce").to_numpy(float) for t in TAGS])
    values, _, _ = _fill(values, np.zeros(len(values), int), pipeline.fill)
    return pipeline.predict_frame(pd.DataFrame(values, columns=TAGS))


def read_log(path):
    import pandas as pd

    log = pd.read_csv(path)
    assert list(log["sample"]) == list(range(ROWS)), "every sample once, in order"
    return log


def same_outputs(log, reference):
    assert np.array_equal(log["alarm"].to_numpy(bool), reference["alarm"].to_numpy(bool))
    for column in ("t2", "spe", "t2_smoothed", "ewma_t2"):  # another code path: the same arithmetic, to 1e-12
        np.testing.assert_allclose(log[column], reference[column], rtol=1e-12, atol=0)
    assert list(log["top_t2"]) == list(reference["top_t2"])


def test_replayed_test_rows_give_the_file_s_alarms_and_are_written_back(tuned, served):
    import asyncio

    import pandas as pd
    from asyncua import Client

    tmp = tuned["tmp"]
    url, epoch = served
    if True:
        live = monitor([*live_args(url, tuned["uri"], tmp, "live", epoch), "--tracking-uri", tuned["tracking"]])
        file = _mosd(["monitor", "--model", tuned["uri"], str(tmp / "test.csv"), "--keep", "time", "--out",
                      str(tmp / "file.csv"), "--tracking-uri", tuned["tracking"]], tmp, tuned["outputs"])
        out, err = live.communicate(timeout=300)
        assert live.returncode == 0, err[-2000:]
        assert file.returncode == 0, file.stderr[-2000:]
        assert f"{ROWS} samples scored" in out and "0 bad-quality values" in out

        async def written():
            async with Client(url) as client:
                ns = await client.get_namespace_index("urn:mosd:monitor")
                return [await client.get_node(f"ns={ns};s=mosd.{c}").read_data_value() for c in ("alarm", "t2")]

        alarm, t2 = asyncio.run(written())
    log = read_log(tmp / "live.csv")
    reference = pd.read_csv(tmp / "file.csv")
    same_outputs(log, reference)
    assert 0 < log["alarm"].sum() < ROWS
    # the last sample's outputs on the server's nodes, stamped with the sample's time
    assert alarm.Value.Value == bool(reference["alarm"].iloc[-1])
    assert t2.Value.Value == pytest.approx(reference["t2"].iloc[-1], rel=1e-12)
    assert t2.SourceTimestamp.timestamp() == pytest.approx(epoch + (ROWS - 1) * 60.0, abs=1e-3)


def _kill_when(process, log: Path, rows: int, sig=signal.SIGKILL, timeout=120):
    """Send ``sig`` to ``process`` once its log holds ``rows`` samples and it has checkpointed at least once."""
    deadline = time.time() + timeout
    while time.time() < deadline and process.poll() is None:
        if log.with_suffix(".json").exists() and log.read_text().count("\n") > rows:
            process.send_signal(sig)
            process.wait(30)
            return True
        time.sleep(0.05)
    return False


def test_monitor_killed_and_restarted_ends_as_an_uninterrupted_run(tuned):
    tmp = tuned["tmp"]
    reference = expected(load_fitted(tuned["npz"]), tuned["coded"])
    with replay_server(tmp / "coded.csv", speed=600) as (url, epoch, _):  # 30 s: the second run stops mid-way
        args = live_args(url, tuned["npz"], tmp, "killed", epoch)
        first = monitor(args)
        assert _kill_when(first, tmp / "killed.csv", 50), first.communicate()[1][-2000:]
        # SIGTERM: the state and the log flushed, exit 0
        second = monitor(args)
        logged = (tmp / "killed.csv").read_text().count("\n")
        assert _kill_when(second, tmp / "killed.csv", logged + 30, signal.SIGTERM), second.communicate()[1][-2000:]
        out, err = second.communicate(timeout=60)
        assert second.returncode == 0, err[-2000:]
        stopped = json.loads((tmp / "killed.json").read_text())
        assert "samples scored" in out and stopped["next_number"] < ROWS
        assert stopped["log_bytes"] == (tmp / "killed.csv").stat().st_size  # the log flushed up to the state
        third = monitor(args)
        out, err = third.communicate(timeout=300)
    assert third.returncode == 0, err[-2000:]
    log = read_log(tmp / "killed.csv")
    same_outputs(log, reference)
    # every Bad cell was counted (in the first run or the second: the counts travel in the state), never used
    assert f"{tuned['bad']} bad-quality values" in out, out
    assert log["missing"].sum() == tuned["bad"]


async def _read_alarm(url):
    from asyncua import Client

    async with Client(url) as client:
        ns = await client.get_namespace_index("urn:mosd:monitor")
        return await client.get_node(f"ns={ns};s=mosd.alarm").read_data_value()


def test_server_killed_and_restarted_mid_stream_is_backfilled_from_its_history(tuned):
    tmp = tuned["tmp"]
    reference = expected(load_fitted(tuned["npz"]), tuned["test"])
    port = free_port()
    with replay_server(tmp / "test.csv", port=port, speed=1000) as (url, epoch, server):
        live = monitor(live_args(url, tuned["npz"], tmp, "dropped", epoch))
        deadline = time.time() + 120
        log = tmp / "dropped.csv"
        while time.time() < deadline and live.poll() is None and (not log.exists() or log.read_text().count("\n") < 60):
            time.sleep(0.05)
        server.send_signal(signal.SIGKILL)
        server.wait(10)
        with replay_server(tmp / "test.csv", port=port, epoch=epoch, speed=1000) as (url, _, _):
            out, err = live.communicate(timeout=300)
            written = asyncio.run(_read_alarm(url))
    assert live.returncode == 0, err[-2000:]
    reconnects = int(re.search(r"(\d+) reconnects", out).group(1))
    assert reconnects >= 1 and " 0 refused writes" in out, out
    log = read_log(tmp / "dropped.csv")
    same_outputs(log, reference)
    # the restarted server lost mosd's nodes: created again, the last sample's alarm written there
    assert written.Value.Value == bool(log["alarm"].iloc[-1]), out
    assert written.SourceTimestamp.timestamp() == pytest.approx(epoch + (ROWS - 1) * 60.0, abs=1e-3), out


def test_without_history_the_samples_before_the_subscription_are_logged_as_missing_rows(tuned):
    """A server that keeps no history: what was published before the monitor subscribed cannot be read back;
    those samples are logged as missing rows (missing = every tag) and counted, the rest scored."""
    import pandas as pd

    tmp = tuned["tmp"]
    with replay_server(tmp / "test.csv", extra=("--no-history",)) as (url, epoch, _):
        time.sleep(max(0.0, epoch + 1.0 - time.time()))  # rows have been published before the monitor starts
        live = monitor(live_args(url, tuned["npz"], tmp, "nohistory", epoch))
        out, err = live.communicate(timeout=300)
    assert live.returncode == 0, err[-2000:]
    log = pd.read_csv(tmp / "nohistory.csv")
    assert list(log["sample"]) == list(range(ROWS))
    gap = log["missing"].to_numpy() == len(TAGS)
    assert gap[0] and set(log["missing"]) <= {0, len(TAGS)}
    assert f"{int(gap.sum())} missing rows" in out and " 0 values from history" in out, out


def _one_line_exit_2(capsys, args, *needles):
    """``mosd monitor`` in this process (no interpreter to start): exit 2, one line naming ``needles``."""
    from mosd.app.monitor import main

    capsys.readouterr()
    assert main([str(a) for a in args]) == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    return err


def test_mistakes_are_one_line_and_exit_2(tuned, served, tmp_path, capsys):
    npz = tuned["npz"]
    url, _ = served
    base = ["--model", npz, "--step", 60, "--timeout", 2, "--no-progress"]
    # a server that accepts the connection and never answers
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        _one_line_exit_2(capsys, ["--opcua", f"opc.tcp://127.0.0.1:{silent.getsockname()[1]}", *base],
                         "did not answer")
    _one_line_exit_2(capsys, ["--opcua", "opc.tcp://user:secret@127.0.0.1:4840", *base], "MOSD_OPCUA_PASSWORD")
    nodes = tmp_path / "nodes.yaml"
    nodes.write_text("".join(f"{t}: {t}\n" for t in TAGS[:-1]) + f"{TAGS[-1]}: ns=2;s=no_such_tag\n")
    _one_line_exit_2(capsys, ["--opcua", url, "--nodes", nodes, *base], "no_such_tag", "not a variable")
    nodes.write_text("".join(f"{t}: {t}\n" for t in TAGS[:-1]) + f"{TAGS[-1]}: Info\n")
    _one_line_exit_2(capsys, ["--opcua", url, "--nodes", nodes, *base], "data type String", "numeric")
    nodes.write_text("".join(f"{t}: {t}\n" for t in TAGS[:-1]))
    _one_line_exit_2(capsys, ["--opcua", url, "--nodes", nodes, *base], f"input {TAGS[-1]!r}")
    _one_line_exit_2(capsys, ["--opcua", url, "--model", npz, "--no-progress"], "--step is required")
    _one_line_exit_2(capsys, ["--opcua", url, "--write", nodes, *base], "is not a column of the model")
    _one_line_exit_2(capsys, ["--opcua", url, "--out", tmp_path / "log.parquet", *base], "allowed: a .csv path")
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": 1, "inputs": ["x"], "step": 60}))
    _one_line_exit_2(capsys, ["--opcua", url, "--state", other, *base], "not a state of this model")


def test_a_missing_extra_is_one_line_naming_it(monkeypatch):
    from mosd.live import require_asyncua
    from mosd.validation import ConfigError

    monkeypatch.setitem(sys.modules, "asyncua", None)  # import asyncua now raises ImportError
    with pytest.raises(ConfigError, match=r"pip install 'mosd\[opcua\]'"):
        require_asyncua()

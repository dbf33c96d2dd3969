"""Issue 32, the fixed part of a small run: Hydra composes a single run's configuration once (preflight's), and
the run directory is the one ``hydra.main`` leaves, file for file."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import mosd as mosd_package

PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])

COUNTING = """
import sys
from hydra._internal.config_loader_impl import ConfigLoaderImpl
calls = []
real = ConfigLoaderImpl.load_configuration
def counting(self, *args, **kwargs):
    calls.append(kwargs.get("run_mode"))
    return real(self, *args, **kwargs)
ConfigLoaderImpl.load_configuration = counting
from mosd.app import main
code = main(sys.argv[1:])
print("COMPOSITIONS", len(calls), code)
"""


def _run(tmp_path: Path, name: str, *extra: str) -> tuple[int, Path]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env.update(PYTHONPATH=PACKAGE_PARENT, MOSD_OUTPUTS=str(tmp_path / "outputs"))
    run_dir = tmp_path / name
    done = subprocess.run([sys.executable, "-c", COUNTING, *extra, "+fault=offset_var", "debug=tiny",
                           "tracking=none", f"hydra.run.dir={run_dir}"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    line, = [ln for ln in done.stdout.splitlines() if ln.startswith("COMPOSITIONS")]
    _, count, code = line.split()
    assert code == "0"
    return int(count), run_dir


@pytest.mark.slow
def test_a_single_run_composes_once_and_writes_what_hydra_main_writes(tmp_path):
    once, fast = _run(tmp_path, "fast")
    # --config-name is left to hydra.main (it composes for its mode, then for the run)
    thrice, reference = _run(tmp_path, "reference", "--config-name", "config")
    assert once == 1 and thrice == 3
    for name in ("config.yaml", "overrides.yaml", "hydra.yaml"):
        ours = (fast / ".hydra" / name).read_text().replace(str(fast), "RUN_DIR")
        theirs = (reference / ".hydra" / name).read_text().replace(str(reference), "RUN_DIR")
        assert ours == theirs, name
    assert sorted(p.name for p in fast.iterdir()) == sorted(p.name for p in reference.iterdir())
    assert "mosd.app" in (fast / "mosd.log").read_text()  # the job's logging is configured as before
    summaries = [json.loads((d / "summary.json").read_text()) for d in (fast, reference)]
    assert summaries[0]["params"] == summaries[1]["params"] and summaries[0]["status"] == "finished"

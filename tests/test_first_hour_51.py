"""Issue 51 item 3: frictions of a user's first hour.

* ``python -m mosd monitor --model … DATA`` compiled its numba kernels for 50-70 s on its first call without a
  word: on a terminal it now says so in one line before, and only when the kernels it needs are not yet in
  numba's on-disk cache (an empty ``NUMBA_CACHE_DIR`` here; the second call finds them and says nothing);
* the ``[table]`` and ``[ml]`` extras added nothing to a plain install (pandas, pyarrow and scikit-learn come
  with mlflow): every extra left in pyproject.toml adds a package the base install lacks.
"""
from __future__ import annotations

import os
import pty
import re
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from test_detector_model import PACKAGE_PARENT, build_logged_run, plant_table

ROOT = Path(__file__).resolve().parents[1]
NOTICE = re.compile(r"mosd monitor: compiling kernels \(first call, (about \d+ s|up to about a minute); "
                    r"cached afterwards\)")


def _monitor_on_a_terminal(args, cache: Path, cwd: Path) -> tuple[int, str]:
    """``python -m mosd monitor ARGS`` with stderr a terminal (a pseudo-terminal read as it writes) and numba's
    cache in ``cache``: (exit code, what the terminal showed)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    env["NUMBA_CACHE_DIR"] = str(cache)
    master, slave = pty.openpty()
    shown = []

    def read():  # the progress bar redraws: read while it writes, or a full terminal buffer blocks the child
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: the child closed the terminal
                return
            if not data:
                return
            shown.append(data)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        process = subprocess.run([sys.executable, "-m", "mosd", "monitor", *map(str, args)], cwd=cwd, env=env,
                                 stdout=subprocess.PIPE, stderr=slave, timeout=600)
    finally:
        os.close(slave)
        reader.join(10)
        os.close(master)
    return process.returncode, b"".join(shown).decode(errors="replace")


@pytest.mark.slow
def test_monitor_says_it_compiles_on_a_cold_cache_and_not_once_cached(tmp_path, shared_build):
    """Before: the first call printed nothing before its kernels compiled (50-70 s on a CI machine)."""
    built = shared_build("pca-table-run", build_logged_run)
    model = re.search(r"model (models:/\S+) ", (built / "stdout.txt").read_text()).group(1)
    plant_table().iloc[900:].drop(columns=["fault"]).to_csv(tmp_path / "test.csv", index=False)
    args = ["--model", model, "--tracking-uri", f"sqlite:///{built / 'out' / 'mlflow.db'}", "--keep", "time",
            tmp_path / "test.csv"]
    cache = tmp_path / "numba-cache"  # empty: nothing compiled yet
    code, first = _monitor_on_a_terminal(args, cache, tmp_path)
    assert code == 0, first[-3000:]
    assert len(NOTICE.findall(first)) == 1, first[-3000:]
    code, second = _monitor_on_a_terminal(args, cache, tmp_path)
    assert code == 0, second[-3000:]
    assert not NOTICE.search(second), second[-3000:]
    # the record of the first call is kept beside numba's own files, in the cache folder mosd was given
    assert (cache / "mosd-first-calls.json").is_file()


def _name(requirement: str) -> str:
    """A requirement's distribution name, normalised (PEP 503): 'scikit_learn>=1.3' -> 'scikit-learn'."""
    return re.sub(r"[-_.]+", "-", re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", requirement).group(1)).lower()


def test_every_extra_adds_a_package_the_base_install_lacks():
    """Before: [table] (pandas, pyarrow) and [ml] (scikit-learn) named only packages mlflow, a base dependency,
    installs: pip install 'mosd[table]' installed nothing more than pip install mosd."""
    import tomllib  # Python 3.11 (as tests/test_readme.py): imported here so that 3.10 still runs the other test

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    base = {_name(r) for r in project["dependencies"]}
    # what the base dependencies bring along: mlflow's own requirements, as installed here
    from importlib.metadata import PackageNotFoundError, requires

    brought = set(base)
    for name in base:
        try:
            brought |= {_name(r) for r in requires(name) or () if "extra ==" not in r}
        except PackageNotFoundError:
            pass
    assert {"pandas", "pyarrow", "scikit-learn"} <= brought  # the premise: a plain install has them
    empty = {extra: sorted(_name(r) for r in requirements)
             for extra, requirements in project.get("optional-dependencies", {}).items()
             if not {_name(r) for r in requirements} - brought}
    assert not empty, f"extras that add nothing to a plain install: {empty}"

"""docs/ADD_A_SYSTEM.md is executable (issue 28 item 6): its excerpts are in the files they name, its
commands run as written and print what the page shows."""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "ADD_A_SYSTEM.md"
BLOCK = re.compile(r"```(\w+)\n(.*?)```", re.S)


def _blocks() -> list[tuple[str, str]]:
    return [(m.group(1), m.group(2)) for m in BLOCK.finditer(PAGE.read_text())]


def _excerpts():
    for language, body in _blocks():
        first, *lines = body.splitlines()
        if language in ("python", "yaml") and first.startswith("# ") and "/" in first:
            yield first[2:].strip(), [line for line in lines if line.strip()]


def _commands():
    """(command, the text block that follows it or None) for every ``python -m`` line of a bash block."""
    blocks = _blocks()
    for i, (language, body) in enumerate(blocks):
        if language != "bash":
            continue
        shown = blocks[i + 1][1] if i + 1 < len(blocks) and blocks[i + 1][0] == "text" else None
        for line in body.splitlines():
            if line.startswith("python -m "):
                yield line.split("  #")[0].strip(), shown


EXCERPTS = list(_excerpts())
COMMANDS = list(_commands())


def test_the_page_names_every_file_of_the_example_and_they_exist():
    text = PAGE.read_text()
    for path in ("mosd/plants/two_tank.py", "conf/plant/two_tank.yaml", "conf/noise/two_tank.yaml",
                 "mosd/estimators/luenberger.py", "conf/estimator/luenberger.yaml", "mosd/detectors/cusum.py",
                 "conf/detector/cusum.yaml", "conf/experiment/two_tank.yaml", "mosd/systems/two_tank.py",
                 "conf/debug/tiny/two_tank.yaml", "tests/test_two_tank.py"):
        assert f"`{path}`" in text and (ROOT / path).is_file(), path
    assert len(EXCERPTS) >= 8 and len(COMMANDS) >= 3


@pytest.mark.parametrize("path,lines", EXCERPTS, ids=[p for p, _ in EXCERPTS])
def test_every_excerpt_is_in_the_file_it_names(path, lines):
    source = {line.strip() for line in (ROOT / path).read_text().splitlines()}
    missing = [line for line in lines if line.strip() not in source]
    assert not missing, f"{path} has no line {missing[0]!r}"


@pytest.mark.parametrize("command,shown", COMMANDS, ids=[c for c, _ in COMMANDS])
def test_every_command_runs_as_written(tmp_path, command, shown):
    env = {**os.environ, "MOSD_OUTPUTS": str(tmp_path / "outputs"), "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, *shlex.split(command)[1:]]
    done = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=400)
    output = done.stdout + done.stderr
    expected_code = 2 if shown is not None and shown.startswith("error:") else 0
    assert done.returncode == expected_code, output[-2000:]
    if shown is not None:
        assert shown.strip() in output

"""docs/ADD_A_SYSTEM.md is executable (issue 28 item 6, issue 50 item 3): its excerpts are in the files they
name, its commands run as written and print what the page shows, and the system it builds from nothing (its
``# NEW`` files) runs in a copy of the repository with no other file changed."""
from __future__ import annotations

import hashlib
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "ADD_A_SYSTEM.md"
BLOCK = re.compile(r"```(\w+)\n(.*?)```", re.S)
#: the first line of a block that is a whole new file of the "From nothing" system (written into a copy)
NEW = "# NEW "


def _blocks() -> list[tuple[str, str]]:
    return [(m.group(1), m.group(2)) for m in BLOCK.finditer(PAGE.read_text())]


def _excerpts():
    for language, body in _blocks():
        first, *lines = body.splitlines()
        if language in ("python", "yaml") and first.startswith("# ") and "/" in first and not first.startswith(NEW):
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
    expected_code = 2 if shown is not None and shown.startswith(("error:", "mosd: error:")) else 0
    assert done.returncode == expected_code, output[-2000:]
    if shown is not None:
        assert shown.strip() in output


# -- a system from nothing, in a copy (issue 50: "CI adds a synthetic system and touches no other file") ------
def _new_files() -> dict[str, str]:
    """path -> content of every ``# NEW path`` block of the page (the block's first line is not the file's)."""
    files = {}
    for language, body in _blocks():
        first, _, rest = body.partition("\n")
        if language in ("python", "yaml") and first.startswith(NEW):
            files[first[len(NEW):].strip()] = rest
    return files


def _shell_commands() -> list[str]:
    return [line.strip() for language, body in _blocks() if language == "shell"
            for line in body.splitlines() if line.startswith("python -m ")]


def _digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and "__pycache__" not in p.parts}


#: prints the site's generated configuration pages (docs/gen_reference.py imported as ``gen_reference``: its page
#: functions, nothing written; in the copy's process, so that the copy's conf/ and classes are read)
PAGES = ("import importlib.util, json; spec = importlib.util.spec_from_file_location('gen_reference', "
         "'docs/gen_reference.py'); module = importlib.util.module_from_spec(spec); spec.loader.exec_module(module); "
         "print(json.dumps(module.config_pages()))")


#: the option-list tests (issue 50 item 1) the new components must pass in the copy, found by their names
OPTION_TESTS = ["tests/test_configs.py", "tests/test_faults_acts_on.py", "tests/test_deploy_presets.py",
                "tests/test_readme_tables.py", "tests/test_exports.py"]
SELECT = ("first_order or intermittent or synthetic or fault_option or acts or every_preset or every_option or readme "
          "or export")


def test_the_page_builds_its_system_from_nothing_in_five_files():
    files = _new_files()
    assert sorted(files) == ["conf/experiment/synthetic.yaml", "conf/fault/intermittent.yaml",
                             "conf/plant/first_order.yaml", "mosd/faults/intermittent.py",
                             "mosd/plants/first_order.py"]
    assert not any((ROOT / path).exists() for path in files), "the page's new files must not be in the repository"
    assert len(_shell_commands()) == 2
    assert "--readme" not in PAGE.read_text()  # nothing to regenerate: the site's reference is built


@pytest.mark.slow  # a copy, a cold kernel cache, a tuning run and ~500 selected tests: 1-3 minutes on 2 cores
def test_a_synthetic_system_runs_in_a_copy_and_no_other_file_changes(tmp_path):
    copy = tmp_path / "repo"
    for name in ("mosd", "conf", "tests", "docs"):
        shutil.copytree(ROOT / name, copy / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy2(ROOT / name, copy / name)
    before = _digests(copy)
    for path, text in _new_files().items():
        (copy / path).write_text(text, encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env.update(PYTHONPATH=str(copy), MOSD_OUTPUTS=str(tmp_path / "outputs"))

    def run(argv, timeout=600):
        return subprocess.run([sys.executable, *argv], cwd=copy, env=env, capture_output=True, text=True,
                              timeout=timeout)

    listed, ran = (run(shlex.split(command)[1:]) for command in _shell_commands())
    for done in (listed, ran):
        assert done.returncode == 0, (done.args, done.stderr[-3000:])
    for option in ("`first_order`", "`intermittent`", "`synthetic`", "mosd.plants.first_order.FirstOrderLag",
                   "Acts on: sensor"):
        assert option in listed.stdout, option
    # the site's configuration reference, generated at build time, lists the new options with nothing regenerated
    generated = run(["-c", PAGES])
    assert generated.returncode == 0, generated.stderr[-3000:]
    pages = json.loads(generated.stdout)
    index = pages["config/index.md"]
    assert "`intermittent` (on sensor)" in index and "`first_order` (takes faults on sensor)" in index
    assert "| `synthetic` | `first_order` | `intermittent` | `luenberger` | `window` | `cusum` |" in index
    assert "## `first_order` {#first_order}" in pages["config/plant.md"]
    assert "mosd.plants.first_order.FirstOrderLag" in pages["config/plant.md"]
    fault = pages["config/fault.md"].split("## `intermittent` {#intermittent}", 1)
    assert len(fault) == 2 and "Acts on: sensor." in fault[1].split("\n## ", 1)[0]
    assert "## `synthetic` {#synthetic}" in pages["config/experiment.md"]
    summary = next((tmp_path / "outputs" / "runs").glob("*/summary.json")).read_text()
    assert '"status": "finished"' in summary and '"model_file"' in summary  # its pipeline streams: deployable
    # the option-list tests pass in the copy, the new components among their cases
    tests = run(["-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "not slow", *OPTION_TESTS, "-k", SELECT])
    assert tests.returncode == 0, tests.stdout[-3000:]
    collected = run(["-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "slow or not slow", "--collect-only",
                     *OPTION_TESTS, "-k", SELECT])
    for case in ("plant=first_order", "fault=intermittent", "experiment=synthetic", "first_order+intermittent",
                 "stream[synthetic]"):
        assert case in collected.stdout, case
    # no file of the copy changed (README, docs/ included): the new ones are the only difference
    after = _digests(copy)
    changed = {path for path in before if after.get(path) != before[path]}
    assert changed == set(), changed
    assert set(after) - set(before) == set(_new_files()), set(after) - set(before) - set(_new_files())

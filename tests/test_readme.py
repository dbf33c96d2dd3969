"""The README is short and its commands run (issue 51 item 1).

Fast: the README has at most 200 lines, none over 300 characters; its fenced blocks are ``bash`` (commands)
or ``text`` (output); every relative link names a file of the repository; its presets table names every
preset; every ``pip install`` names extras that pyproject.toml declares; a command quoted inline (a
reference, not a step to run) names an existing module.

Slow (:func:`test_the_readme_commands_run`): every ``bash`` block, in order, in one empty directory, as one
bash session (``bash -euo pipefail``), with these substitutions, each checked otherwise:

* ``python3 -m venv .venv`` and ``. .venv/bin/activate``: not run (the test runs in the project's own
  environment); checked for syntax (``bash -n`` of the whole block) like everything else.
* ``pip install SPEC``: not run; SPEC must be ``.`` or ``".[extra,...]"`` with extras pyproject.toml declares.
* a tuning command (``python -m mosd`` with ``+fault=``/``+experiment=`` overrides) gets ``debug=tiny``
  appended: the same pipeline in seconds, with MLflow on, so that its model exists for the next commands.
* ``python -m pytest ...``: not run here (it is the test suite): the fast-suite command collects this file
  with the same options (so its flags and markers parse and pytest-xdist is installed), and the whole
  command is the one ``.ci/run`` runs verbatim.
* ``mkdocs serve``: a server; ``mkdocs serve --help`` must succeed (``tests/test_docs.py`` builds the site
  with ``mkdocs build --strict``).
* a command ending with ``&`` (``mlflow models serve``): started in the background (its output to
  ``server.log``, on a free port instead of the README's 5001); the next command waits
  until its port answers ``/ping`` (at most 180 s), and the server is stopped when the block ends. The
  ``curl`` that follows must answer one prediction per posted row.

The own-data commands read ``plant.csv``: the test writes a synthetic labelled table there first (four
correlated tags, a bias on one in labelled episodes, the first half normal), as the README describes it.
"""
from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mosd.app.config import options
from mosd.app.serving import free_port

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
FENCE = re.compile(r"^```([^\s`]*)[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)
MAX_LINES, MAX_WIDTH = 200, 300

#: a tuning command: python -m mosd with a preset or a fault (not monitor, report, options, ui, log)
TUNING = re.compile(r"(python -m mosd (?:-m )?[^\n&|#]*?\+(?:fault|experiment)=[^\n&|#]*?)(\s*(?:#.*)?$|\s+&&)", re.M)
SETUP = re.compile(r"(python3 -m venv \S+|\. \S+/bin/activate|pip install (\S+))( && |$)", re.M)
PYTEST = re.compile(r"^python -m pytest .*$", re.M)


def _text() -> str:
    return README.read_text(encoding="utf-8")


def _blocks() -> list[tuple[str, str]]:
    return [(m[1], m[2]) for m in FENCE.finditer(_text())]


def _bash() -> list[str]:
    return [body for lang, body in _blocks() if lang == "bash"]


# -- fast ----------------------------------------------------------------------------------------------------


def test_the_readme_is_short():
    lines = _text().splitlines()
    assert len(lines) <= MAX_LINES, f"README.md has {len(lines)} lines; allowed: at most {MAX_LINES} (the rest: docs/)"
    wide = [(n, len(line)) for n, line in enumerate(lines, 1) if len(line) > MAX_WIDTH]
    assert not wide, f"README.md lines over {MAX_WIDTH} characters (line, length): {wide}"


def test_the_readme_blocks_are_commands_or_output():
    langs = [lang for lang, _ in _blocks()]
    assert set(langs) <= {"bash", "text"}, f"README.md fences {set(langs) - {'bash', 'text'}}; allowed: bash, text"
    assert langs.count("bash") >= 5


def test_the_readme_links_name_files_of_the_repository():
    links = re.findall(r"\]\(((?!https?://|#)[^)#\s]+)(?:#[^)]*)?\)", _text())
    assert len(links) >= 20, links
    missing = [link for link in links if not (ROOT / link).is_file()]
    assert not missing, f"README.md links to missing files: {missing}"


def test_the_readme_inline_commands_name_existing_modules():
    """The commands quoted inline (`python -m MODULE ...`, references to the blocks' and the site's commands)
    name modules that exist; the ``mosd`` subcommands among them are ones the app knows."""
    import importlib.util

    inline = re.findall(r"`python -m ([\w.]+)([^`]*)`", _text())
    assert len(inline) >= 3, inline
    for module, rest in inline:
        assert importlib.util.find_spec(module) is not None, f"README names python -m {module}, which does not exist"
        sub = rest.split()[0] if rest.split() else ""
        if module == "mosd" and sub and not sub.startswith(("+", "-")) and "=" not in sub:
            assert sub in ("monitor", "options", "report", "ui", "log"), f"README: python -m mosd {sub}?"


def test_the_readme_presets_table_names_every_preset():
    rows = re.findall(r"^\| `(\w+)` \|", _text().split("## The presets", 1)[1].split("\n## ", 1)[0], re.M)
    assert sorted(rows) == sorted(options("experiment")), (sorted(rows), sorted(options("experiment")))


def test_the_readme_installs_only_declared_extras():
    import tomllib

    extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    specs = [m[2] for body in _bash() for m in SETUP.finditer(body) if m[2]]
    assert "." in specs and len(specs) >= 3, specs
    for spec in specs:
        named = re.fullmatch(r'"\.\[([\w,-]+)\]"|\.', spec)
        assert named, f"README: pip install {spec}; allowed: . or \".[extra,...]\""
        unknown = set((named[1] or "").split(",")) - {""} - extras
        assert not unknown, f"README: pip install {spec} names extras pyproject.toml lacks: {sorted(unknown)}"


def test_the_readme_test_commands_are_what_ci_runs():
    commands = [m[0] for body in _bash() for m in PYTEST.finditer(body)]
    full = [c for c in commands if "serial" in c]
    assert full and full[0] in (ROOT / ".ci" / "run").read_text(), "the README's full test command is not .ci/run's"
    fast = [line.split("&& ", 1)[-1] for body in _bash() for line in body.splitlines()
            if "python -m pytest -n auto" in line and "serial" not in line]
    assert fast, "the README shows no fast-suite command"
    argv = shlex.split(fast[0])[1:]
    # the same options on this file only: they parse, the markers expression is valid, xdist is installed
    done = subprocess.run([sys.executable, *argv, "--collect-only", "-q", "-p", "no:cacheprovider",
                           str(Path(__file__))], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "test_the_readme_is_short" in done.stdout, done.stdout[-2000:] + done.stderr[-2000:]


def test_the_transformation_runs_what_the_readme_says():
    """The substitutions of the slow test, on a sample block: set-up lines out, debug=tiny on tuning commands."""
    block = ('python3 -m venv .venv && . .venv/bin/activate && pip install . && python -m mosd +fault=offset_var '
             'optimizer=mopso\npython -m mosd +experiment=table data.path=plant.csv   # a comment\n'
             'python -m mosd monitor --model "$model" plant.csv\n'
             'mlflow models serve -m "$model" --port 5001 &\ncurl -s x\n')
    script, specs = runnable(block)
    assert specs == ["."]
    lines = script.splitlines()
    assert lines[0] == "python -m mosd +fault=offset_var optimizer=mopso debug=tiny"
    assert lines[1].startswith("python -m mosd +experiment=table data.path=plant.csv debug=tiny")
    assert lines[2] == 'python -m mosd monitor --model "$model" plant.csv'
    assert 'mlflow models serve -m "$model" --port 5001 > server.log 2>&1 &' in lines
    assert "/ping" in script and script.rstrip().endswith("curl -s x")


def runnable(block: str) -> tuple[str, list[str]]:
    """(the block as the test runs it, the pip install specs it had): see the module's docstring."""
    specs = [m[2] for m in SETUP.finditer(block) if m[2]]
    script = SETUP.sub("", block)
    script = TUNING.sub(lambda m: f"{m[1].rstrip()} debug=tiny{m[2]}", script)
    script = PYTEST.sub("", script)
    script = re.sub(r"^(.*)mkdocs serve$", r"\1mkdocs serve --help > /dev/null", script, flags=re.M)
    out = []
    for line in script.splitlines():
        if line.rstrip().endswith("&"):  # its log to a file: the block's stdout is the curl's answer alone
            line = line.rstrip()[:-1].rstrip() + " > server.log 2>&1 &"
        out.append(line)
        if line.endswith("&"):
            port = re.search(r"--port (\d+)", line)
            assert port, f"a background command without --port: {line}"
            out += ["__server=$!", "trap 'kill $__server 2>/dev/null || true' EXIT",
                    f"for i in $(seq 180); do curl -sf 127.0.0.1:{port[1]}/ping > /dev/null && break; sleep 1; done"]
    return "\n".join(out) + "\n", specs


# -- slow: run them ------------------------------------------------------------------------------------------


def _plant_csv(path: Path) -> None:
    """A labelled table as the README describes it: time, four correlated tags, fault (the first half normal)."""
    rng = np.random.default_rng(0)
    n = 1200
    latent = rng.normal(size=(n, 2))
    tags = latent @ rng.normal(size=(2, 4)) + 0.1 * rng.normal(size=(n, 4))
    fault = np.zeros(n, int)
    fault[700:900] = 1
    fault[1000:] = 1
    tags[fault == 1, 2] += 0.8
    rows = ["time,level,pressure,flow,temperature,fault"]
    rows += [",".join([f"{10.0 * i:g}", *(f"{v:.6f}" for v in tags[i]), str(fault[i])]) for i in range(n)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


@pytest.mark.slow  # four debug=tiny runs, a model server and a file scored: 2-4 minutes on 2 loaded cores
def test_the_readme_commands_run(tmp_path):
    """Every bash block of the README, in order, in one empty directory (see the module's docstring)."""
    home = tmp_path / "readme"
    home.mkdir()
    _plant_csv(home / "plant.csv")
    env = {k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "MOSD_OUTPUTS")}
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    scripts = []
    for body in _bash():
        syntax = subprocess.run(["bash", "-n", "-c", body], capture_output=True, text=True)
        assert syntax.returncode == 0, f"README block is not valid bash:\n{body}\n{syntax.stderr}"
        scripts.append(runnable(body)[0])
    # each block's output ends with a newline (curl's answer has none); a server's block is a subshell, whose
    # exit stops the server; the README's port is replaced by a free one (other tests serve on 5001 too)
    session = "\n".join((f"( {script}\n)" if "&\n" in script else script.rstrip("\n")) + "\necho" for script in scripts)
    port = str(free_port())
    session = session.replace("--port 5001", f"--port {port}").replace("127.0.0.1:5001", f"127.0.0.1:{port}")
    done = subprocess.run(["bash", "-euo", "pipefail", "-c", session], cwd=home, env=env, capture_output=True,
                          text=True, timeout=1500, start_new_session=True)
    assert done.returncode == 0, (f"the README's commands exited {done.returncode}:\n{session}\n--- stdout ---\n"
                                  f"{done.stdout[-4000:]}\n--- stderr ---\n{done.stderr[-4000:]}")
    answer = json.loads(re.search(r'^\{"predictions".*$', done.stdout, re.M)[0])
    assert len(answer["predictions"]) == 5 and answer["predictions"][-1]["limit"] is not None, answer
    scored = (home / "alarms.csv").read_text().splitlines()
    assert len(scored) == 1201 and scored[0].startswith("time,fault,"), scored[:2]
    runs = sorted((home / "outputs" / "runs").iterdir())
    assert len(runs) == 3 and all(json.loads((r / "summary.json").read_text())["status"] == "finished" for r in runs)

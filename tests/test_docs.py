"""The documentation site (issue 51 item 2): it builds strictly, its reference lists every config group,
option and key, and the ``bash`` and ``python`` blocks of Getting started, the tutorials and the how-to
guides run as written.

The convention (docs/index.md, "Writing these pages"): in those pages every ```` ```bash ```` and
```` ```python ```` block runs, each page in its own empty directory, its blocks in order; a command that
cannot run here goes in a ```` ```console ```` block (shown, not run), and ```` ```sh ````/```` ```shell ````
are refused there. A missing docs dependency (the ``docs`` extra, also in ``test``) fails, it never skips.

The OPC UA how-to (``how-to/opcua.md``) runs too: it needs the ``opcua`` and ``te`` extras (both in ``test``),
and one of its blocks starts a replay server on 127.0.0.1:4840 that the block stops when it ends (its own
process group is killed as well). The README's commands run in ``tests/test_readme.py``.
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

#: the pages whose blocks run: Getting started, the tutorials, the how-to guides and the new explanation pages
EXECUTED = ["getting-started.md",
            *sorted(str(p.relative_to(DOCS)) for p in (DOCS / "tutorials").glob("*.md")),
            *sorted(str(p.relative_to(DOCS)) for p in (DOCS / "how-to").glob("*.md")),
            *sorted(str(p.relative_to(DOCS)) for p in (DOCS / "explanation").glob("*.md"))]
RUN = {"bash", "python"}
REFUSED = {"sh", "shell", "zsh"}

#: a fenced block at the start of a line: its language (the info string's first word) and its text
FENCE = re.compile(r"^```([^\s`]*)[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)

#: the modules the docs extra brings (mkdocs.yml's theme and plugins); an ImportError fails the test
DOCS_MODULES = ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python", "mkdocs_gen_files",
                "mkdocs_literate_nav", "pymdownx")

#: seconds one block may take (a tutorial's block is a debug=tiny run: tens of seconds on 2 loaded cores)
BLOCK_TIMEOUT_S = 400


def fenced(text: str) -> list[tuple[str, str]]:
    """(language, text) of each fenced block of a page's markdown, in order."""
    return [(m[1], m[2]) for m in FENCE.finditer(text)]


def blocks(page: str) -> list[tuple[str, str]]:
    """(language, text) of each fenced block of ``docs/<page>``, in order."""
    return fenced((DOCS / page).read_text(encoding="utf-8"))


def runnable(found: list[tuple[str, str]]) -> list[tuple[int, str, str]]:
    """(1-based number among the page's blocks, language, text) of the blocks that run."""
    return [(i, lang, text) for i, (lang, text) in enumerate(found, 1) if lang in RUN]


def executed_blocks(page: str) -> list[tuple[int, str, str]]:
    return runnable(blocks(page))


def _env() -> dict:
    env = dict(os.environ)
    # the project's Python first on PATH (a bash block's `python` is the one running the tests); runs write
    # their store under the page's own directory, never to a tracking server named by the environment
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    for key in ("MLFLOW_TRACKING_URI", "MOSD_OUTPUTS"):
        env.pop(key, None)
    return env


def _tail(text: str, lines: int = 40) -> str:
    return "\n".join(text.splitlines()[-lines:])


# -- fast: the convention ---------------------------------------------------------------------------------


def test_the_executed_pages_follow_the_convention():
    """Each executed page exists, is in the site, uses bash/python/console/text/yaml fences only, and every
    tutorial and how-to page with a command runs one."""
    import yaml

    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    yaml.safe_load(nav)  # plain YAML: no tags
    for page in EXECUTED:
        if page != "getting-started.md" and not page.endswith("index.md"):
            assert page in nav, f"docs/{page} is not in mkdocs.yml's nav"
        refused = [lang for lang, _ in blocks(page) if lang in REFUSED]
        assert not refused, (f"docs/{page}: a ```{refused[0]} block; allowed: ```bash or ```python (run in CI) "
                             "or ```console (shown, not run): docs/index.md, 'Writing these pages'")
    assert executed_blocks("getting-started.md"), "Getting started runs no block"
    for page in EXECUTED:
        if page.startswith("tutorials/") and not page.endswith("index.md"):
            assert executed_blocks(page), f"docs/{page}: a tutorial with no bash or python block"


def test_fences_are_parsed_as_written():
    text = ("a\n```bash\necho 1\n```\n\n```console\nrm -rf /\n```\n```python title=\"x\"\nprint(2)\n```\n"
            "```text\n| a |\n```\n")
    found = fenced(text)
    assert found == [("bash", "echo 1\n"), ("console", "rm -rf /\n"), ("python", "print(2)\n"), ("text", "| a |\n")]
    assert [n for n, _, _ in runnable(found)] == [1, 3]


def test_a_failing_block_names_the_page_and_the_block(tmp_path):
    found = runnable(fenced("```bash\necho fine\n```\n```console\nnot run\n```\n"
                            "```python\nraise SystemExit('the third block fails')\n```\n"))
    with pytest.raises(pytest.fail.Exception) as failed:
        run_blocks("tutorials/example.md", found, tmp_path)
    message = str(failed.value)
    assert "docs/tutorials/example.md, block 3 (python) exited 1" in message
    assert "the third block fails" in message


def test_the_docs_dependencies_are_installed():
    """The docs extra is installed (the test extra has it): missing, this fails, never skips."""
    for name in DOCS_MODULES:
        importlib.import_module(name)


def test_the_reference_generator_lists_every_group_option_and_key():
    """docs/gen_reference.py's pages hold every config group, every option and every key with its domain."""
    sys.path.insert(0, str(DOCS))
    try:
        import mkdocs_gen_files  # noqa: F401  (the generator imports it at module level)

        spec = importlib.util.spec_from_file_location("gen_reference_check", DOCS / "gen_reference.py")
        gen = importlib.util.module_from_spec(spec)
        written = {}

        class _Open:
            def __init__(self, path, mode="w"):
                self.path = path

            def __enter__(self):
                return self

            def write(self, text):
                written[self.path] = written.get(self.path, "") + text

            def __exit__(self, *exc):
                return False

        import mkdocs_gen_files as files

        original = files.open
        files.open = _Open
        try:
            spec.loader.exec_module(gen)
        finally:
            files.open = original
    finally:
        sys.path.remove(str(DOCS))

    from mosd.app.config import groups
    from mosd.app.options import listing

    summary = written["reference/SUMMARY.md"]
    for group, opts in listing().items():
        page = written[f"reference/config/{group}.md"]
        assert f"(config/{group}.md)" in summary, f"reference/SUMMARY.md does not link {group}"
        for opt in opts:
            heading = f"## `{opt.name}` {{#{opt.name}}}\n"
            assert heading in page, f"reference/config/{group}.md lacks option {opt.name}"
            section = page.split(heading, 1)[1].split("\n## ", 1)[0]
            for key in opt.keys:
                row = f"| `{key.name}` | `{key.default.replace('|', chr(92) + '|')}` | "
                assert row in section, f"reference/config/{group}.md: {opt.name} lacks key {key.name} = {key.default}"
                if key.declared:
                    assert key.declared.replace("|", "\\|") in section.split(row, 1)[1].split("\n", 1)[0], (
                        f"reference/config/{group}.md: {opt.name}.{key.name} lacks its domain {key.declared}")
    assert set(groups()) == {p.split("/")[-1][:-3] for p in written if p.startswith("reference/config/")} - {"index"}
    for package in gen.PACKAGES:
        assert f"::: {package}" in written[f"reference/api/{package}.md"]


# -- slow: the build and the blocks -----------------------------------------------------------------------


@pytest.mark.slow
def test_the_site_builds_strictly(tmp_path):
    """``mkdocs build --strict`` passes, and the built reference has a page per config group."""
    for name in DOCS_MODULES:
        importlib.import_module(name)
    site = tmp_path / "site"
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1", DISABLE_MKDOCS_2_WARNING="true")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                           "-d", str(site)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"mkdocs build --strict failed (exit {done.returncode}):\n{_tail(done.stderr, 60)}"
    from mosd.app.config import groups

    for group in groups():
        assert (site / "reference" / "config" / group / "index.html").is_file(), f"no reference page for {group}"
    for page in EXECUTED:
        built = site / page.replace(".md", "/index.html").replace("index/index.html", "index.html")
        assert built.is_file(), f"docs/{page} was not built ({built})"


def _executed_pages():
    return [pytest.param(page, id=page[:-3]) for page in EXECUTED if executed_blocks(page)]


@pytest.mark.slow
@pytest.mark.parametrize("page", _executed_pages())
def test_the_page_runs_as_written(page, tmp_path):
    """Every bash and python block of the page, in order, in an empty directory: each exits 0."""
    home = tmp_path / "page"
    home.mkdir()
    if page == "tutorials/skab.md":
        skab = os.environ.get("MOSD_SKAB")
        if not skab:
            pytest.skip("MOSD_SKAB is not set: the SKAB tutorial was not run (MOSD_SKAB=SKAB/data runs it; "
                        ".ci/run sets it)")
        assert Path(skab).is_dir(), f"MOSD_SKAB={skab} is not a directory"
        (home / "SKAB").mkdir()
        (home / "SKAB" / "data").symlink_to(Path(skab).resolve())
    run_blocks(page, executed_blocks(page), home)


def run_blocks(page: str, found: list[tuple[int, str, str]], home: Path) -> None:
    """Run ``found`` (from :func:`runnable`) in order in ``home``; the first that fails fails the test, naming
    ``docs/<page>``, the block's number and language, its text and the tail of its output."""
    env = _env()
    for number, lang, text in found:
        if lang == "bash":
            command = ["bash", "-euo", "pipefail", "-c", text]
        else:
            script = home / f".block{number}.py"
            script.write_text(text, encoding="utf-8")
            command = [sys.executable, str(script)]
        # its own process group: whatever the block left running (a server it started) ends with it
        block = subprocess.Popen(command, cwd=home, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True, start_new_session=True)
        try:
            stdout, stderr = block.communicate(timeout=BLOCK_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            _end_group(block)
            stdout, stderr = block.communicate()
            pytest.fail(f"docs/{page}, block {number} ({lang}) ran past {BLOCK_TIMEOUT_S} s:\n{text}\n"
                        f"--- stdout ---\n{_tail(stdout)}\n--- stderr ---\n{_tail(stderr)}")
        finally:
            _end_group(block)
        if block.returncode != 0:
            pytest.fail(f"docs/{page}, block {number} ({lang}) exited {block.returncode}:\n{text}\n"
                        f"--- stdout ---\n{_tail(stdout)}\n--- stderr ---\n{_tail(stderr)}")


def _end_group(process: subprocess.Popen) -> None:
    """SIGKILL the process group the block started (its own id), if anything of it is left."""
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass

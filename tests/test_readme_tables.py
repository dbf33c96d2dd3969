"""The documented lists of options are the components, not a hand list (issue 50 item 3).

The index of every preset and option, :func:`mosd.app.options.option_index`, is on the site's
generated configuration page (``reference/config/index.md``, written by ``docs/gen_reference.py`` when
the site is built, never committed), next to a generated page per config group: a component added (one
module and one YAML) appears there with no file to edit, and this test fails naming an option the
generated pages miss. The curated tables (the README's presets table, the reference page's per-group
tables) are a selection: each of their rows must name an existing option (``tests/test_configs.py``
checks the classes; ``tests/test_readme.py`` that the README's presets table names every preset).
"""
from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import mosd.app
from mosd.app import options as options_module
from mosd.app.config import groups, options

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _gen_reference():
    """docs/gen_reference.py imported as ``gen_reference``: its page functions, nothing written."""
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "docs" / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _named(block: str) -> set[tuple[str, str]]:
    """(group, option) of every option the index names: the presets' rows and each group's row."""
    named = set()
    for line in block.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        group = re.fullmatch(r"\[?`(\w+)`(?:\]\(\w+\.md\))?", cells[0])
        if line.startswith("| ") and len(cells) == 2 and group:
            named |= {(group.group(1), name) for name in re.findall(r"`(\w+)`", cells[1])}
        elif line.startswith("| `") and group:
            named.add(("experiment", group.group(1)))
    return named


def test_the_generated_index_names_every_option_and_no_other():
    pages = _gen_reference().config_pages()
    index = options_module.option_index(group_pages=True)
    assert index in pages["config/index.md"], "the site's configuration page does not show option_index()"
    on_disk = {(g, o) for g in groups() for o in options(g)}
    named = _named(index)
    assert not on_disk - named, f"the generated index misses {sorted(on_disk - named)}"
    assert not named - on_disk, f"the generated index names {sorted(named - on_disk)}, which conf/ lacks"
    # each option also has its section on its group's generated page
    for group, name in sorted(on_disk):
        assert f"## `{name}` {{#{name}}}" in pages[f"config/{group}.md"], (group, name)


def test_the_index_says_where_each_fault_acts_and_each_plant_takes_faults():
    row = {line.split("|")[1].strip(): line for line in options_module.option_index().splitlines()
           if line.startswith("| `")}
    for name in options("fault"):
        acts_on = options_module.option("fault", name).acts_on
        assert acts_on and f"`{name}` (on {acts_on})" in row["`fault`"], name
    for name in options("plant"):
        assert f"`{name}` (takes faults on " in row["`plant`"], name
    # a preset's fault acts where its plant takes faults (what Plant.check_fault enforces)
    for preset, choices in options_module.presets().items():
        if choices.get("plant") and choices.get("fault") and not choices.get("data"):
            assert choices["fault"] in options_module.faults_for(choices["plant"]), (preset, choices)


def test_the_curated_preset_table_names_existing_presets():
    """Each row of the README's presets table names a preset of conf/ (that it names every preset is
    ``tests/test_readme.py``'s check, which ``tests/test_add_a_system.py``'s throw-away system does not run)."""
    section = README.read_text(encoding="utf-8").split("\n## The presets\n", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `(\w+)` \|", section, re.M)
    assert rows and set(rows) <= set(options("experiment")), set(rows) - set(options("experiment"))


def test_the_options_command_has_no_page_rewriting_flag(capsys):
    """The index is generated when the site is built: ``--readme`` (which rewrote a committed copy) is gone,
    and asking for it is one line, exit 2."""
    assert mosd.app.main(["options", "--readme", "docs/reference/options.md"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "mosd: error: options: unrecognized arguments: --readme", err

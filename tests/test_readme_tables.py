"""The documented lists of options are the components, not a hand list (issue 50 item 3).

The index of every preset and option between the generated markers of the configuration
reference, ``docs/reference/options.md`` (the README's until issue 51 moved it to the site), is
:func:`mosd.app.options.readme_index` (``mosd options --readme docs/reference/options.md``
rewrites it): a component added (one module and one YAML) or removed makes it stale, and
this test fails naming the option. The curated tables (the README's presets table, the
reference page's per-group tables) are a selection: each of their rows must name an existing
option (``tests/test_configs.py`` checks the classes).
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from mosd.app import options as options_module
from mosd.app.config import groups, options

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: the page that holds the generated index (:data:`mosd.app.options.PAGE`)
PAGE = ROOT / options_module.PAGE
REGENERATE = f"run mosd options --readme {options_module.PAGE}"


def _block(text: str) -> str:
    start, stop = text.index(options_module.BEGIN), text.index(options_module.END)
    return text[start + len(options_module.BEGIN):stop].strip("\n")


def _named(block: str) -> set[tuple[str, str]]:
    """(group, option) of every option the index names: the presets' rows and each group's row."""
    named = set()
    for line in block.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        group = re.fullmatch(r"`(\w+)`", cells[0])
        if line.startswith("| `") and len(cells) == 2 and group:
            named |= {(group.group(1), name) for name in re.findall(r"`(\w+)`", cells[1])}
        elif line.startswith("| `") and group:
            named.add(("experiment", group.group(1)))
    return named


def test_the_readme_index_names_every_option_and_no_other():
    block = _block(PAGE.read_text(encoding="utf-8"))
    on_disk = {(g, o) for g in groups() for o in options(g)}
    named = _named(block)
    assert not on_disk - named, f"{options_module.PAGE}'s index misses {sorted(on_disk - named)}: {REGENERATE}"
    assert not named - on_disk, f"{options_module.PAGE}'s index names {sorted(named - on_disk)}, which conf/ lacks"
    assert block == options_module.readme_index(), f"{options_module.PAGE}'s index is stale: {REGENERATE}"


def test_the_index_says_where_each_fault_acts_and_each_plant_takes_faults():
    row = {line.split("|")[1].strip(): line for line in options_module.readme_index().splitlines()
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


def test_the_generator_rewrites_a_stale_index_and_refuses_a_file_without_one(tmp_path):
    text = PAGE.read_text(encoding="utf-8")
    stale = tmp_path / "options.md"
    stale.write_text(text.replace(_block(text), "| stale |"), encoding="utf-8")
    command = [sys.executable, "-m", "mosd", "options", "--readme"]
    done = subprocess.run([*command, str(stale)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert _block(stale.read_text(encoding="utf-8")) == options_module.readme_index()
    plain = tmp_path / "plain.md"
    plain.write_text("no markers\n", encoding="utf-8")
    refused = subprocess.run([*command, str(plain)], capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1, refused.stderr
    assert "allowed: both markers" in refused.stderr and "Traceback" not in refused.stderr
    assert plain.read_text(encoding="utf-8") == "no markers\n"


@pytest.mark.parametrize("text", ["no block at all", options_module.END + "\n" + options_module.BEGIN])
def test_with_index_refuses_missing_or_swapped_markers(text):
    with pytest.raises(ValueError, match="allowed: both markers, in that order"):
        options_module.with_index(text)

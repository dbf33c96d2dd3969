"""Issue 51: ``--help`` names every subcommand and ``--version`` prints mosd's version (it printed Hydra's)."""
from __future__ import annotations

import re
from importlib.metadata import version

from mosd.app import main

SUBCOMMANDS = ("report", "monitor", "ui", "log", "options")


def test_version_is_mosds(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"mosd {version('mosd')}" and "Hydra" not in out


def test_help_lists_every_subcommand_and_each_has_its_own_help(capsys):
    import pytest

    with pytest.raises(SystemExit) as info:  # Hydra's --help exits
        main(["--help"])
    assert info.value.code in (0, None)
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if line.startswith("Commands:"))
    assert set(re.findall(r"\b[a-z]+\b", line.split("mosd", 1)[1])) >= set(SUBCOMMANDS)
    for command in SUBCOMMANDS:
        try:
            code = main([command, "--help"])
        except SystemExit as exc:  # argparse's --help exits
            code = exc.code
        assert code in (0, None), command
        assert "usage" in capsys.readouterr().out.lower(), command

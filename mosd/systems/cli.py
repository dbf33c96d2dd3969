"""What every report command shares: argument parsing, one-line errors with exit 2, the preset, the output.

``python -m mosd.systems.paperNNN``, ``python -m mosd.systems.oc_curves`` and
``python -m mosd.paper`` are built from :func:`report_parser` and :func:`run_report`. Their
experiment is the preset's (:func:`preset`, composed by :mod:`mosd.app.presets` and imported
only when a command runs, so that importing ``mosd.systems`` never loads Hydra).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from ..validation import ConfigError


class ReportParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr and exit code 2 (no usage block)."""

    def error(self, message: str):
        self.exit(2, f"error: {self.prog}: {message}\n")


def report_parser(prog: str, description: str, out: str, seed: bool = True) -> ReportParser:
    """A report command's parser with the options every one has: ``--seed`` (root seed) and ``--out``."""
    parser = ReportParser(prog=prog, description=description)
    if seed:
        parser.add_argument("--seed", type=int, default=0, help="root seed; the test stream is reported (default 0)")
    parser.add_argument("--out", default=out, help=f"directory of the figures and files (default {out})")
    return parser


def run_report(parser: argparse.ArgumentParser, argv: Sequence[str] | None,
               body: Callable[[argparse.Namespace], Iterable[Path]]) -> int:
    """Parse ``argv``, run ``body(args)`` and list the files it wrote; bad input is one line and exit 2.

    ``body`` validates before it writes anything: a :class:`ConfigError` (an option outside its
    range, a preset override Hydra refuses) is printed as ``error: ...`` and returns 2.
    """
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    try:
        files = list(body(args))
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote: {', '.join(str(p) for p in files)}  ({time.perf_counter() - t0:.1f} s)")
    return 0


def preset(name: str, overrides: Sequence[str] = ()):
    """The :class:`~mosd.app.build.Setup` of ``+experiment=NAME`` with Hydra ``overrides`` (imports Hydra now)."""
    from ..app.presets import preset_setup

    return preset_setup(name, overrides)


def component(group: str, option: str, overrides: Sequence[str] = ()):
    """A fresh component of ``conf/GROUP/OPTION.yaml`` with Hydra ``overrides`` (imports Hydra now)."""
    from ..app.presets import component as make

    return make(group, option, overrides)


def write_json(path: Path, payload: Any) -> Path:
    """``payload`` as indented JSON at ``path`` (its directory created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(payload, indent=1))
    return path

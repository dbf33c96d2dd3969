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

from ..metrics.summary import json_ready
from ..validation import ConfigError
from .base import NO_RECORDED_DESIGN, TUNED, has_recorded_design, recorded_designs


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


def design_options(parser: argparse.ArgumentParser, system: str) -> None:
    """One option per parameter of the system's recorded tuned design, defaulting to it (``mu_T`` → ``--mu-T``).

    None for a system with no recorded design yet (:func:`tuned_design` then says so).
    """
    if not has_recorded_design(system):
        return
    for name, value in recorded_designs(system)[TUNED].items():
        parser.add_argument("--" + name.replace("_", "-"), dest=name, type=type(value), default=value,
                            help=f"tuned {name} (default {value:g}: the recorded design, "
                                 f"mosd/systems/designs/{system}.json)")


def tuned_design(args: argparse.Namespace, system: str) -> dict[str, Any]:
    """The tuned design the command line asked for (:func:`design_options`).

    Raises
    ------
    ConfigError
        "no recorded design yet" (one line, exit 2 in :func:`run_report`) when the system has none.
    """
    if not has_recorded_design(system):
        raise ConfigError(NO_RECORDED_DESIGN.format(system=system))
    return {name: getattr(args, name) for name in recorded_designs(system)[TUNED]}


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A markdown table of already formatted cells."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def run_report(parser: argparse.ArgumentParser, argv: Sequence[str] | None,
               body: Callable[[argparse.Namespace], Iterable[Path]]) -> int:
    """Parse ``argv``, run ``body(args)`` and list the files it wrote; bad input is one line and exit 2.

    ``body`` validates before it writes anything: a :class:`ConfigError` (an option outside its
    range, a preset override Hydra refuses) is printed as ``error: ...`` and returns 2.
    """
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    try:
        for option in ("out", "export"):  # before the work, not after it (issue 53: /proc/fam after the tuning)
            if getattr(args, option, None):
                check_writable_folder(getattr(args, option), f"--{option}")
        files = list(body(args))
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote: {', '.join(str(p) for p in files)}  ({time.perf_counter() - t0:.1f} s)")
    return 0


def check_writable_folder(folder, option: str) -> None:
    """One-line ConfigError unless ``folder`` can be (created as) a folder this user writes in, with room for a
    report; creates nothing (the preflight's own check, :func:`mosd.app.checks.writable_dir_problem`)."""
    from ..app.checks import writable_dir_problem

    problem = writable_dir_problem(Path(folder))
    if problem is not None:
        raise ConfigError(f"{option}={str(folder)!r} cannot be written ({problem}); allowed: a folder this user "
                          "can create or write")


def preset(name: str, overrides: Sequence[str] = ()):
    """The :class:`~mosd.app.build.Setup` of ``+experiment=NAME`` with Hydra ``overrides`` (imports Hydra now)."""
    from ..app.presets import preset_setup

    return preset_setup(name, overrides)


def component(group: str, option: str, overrides: Sequence[str] = ()):
    """A fresh component of ``conf/GROUP/OPTION.yaml`` with Hydra ``overrides`` (imports Hydra now)."""
    from ..app.presets import component as make

    return make(group, option, overrides)


def score(study, experiment, designs: dict, out: Path, **record) -> tuple[dict, dict[str, float], list[Path]]:
    """What a report command does with its designs: the study's data, metrics and figures in ``out``.

    Also writes ``<system>_study.json`` with the metrics, the designs' parameters
    (``data["params"]``) and ``record`` (the command's settings; a callable value is applied to
    the data, for tables computed by the study). Returns (data, metrics, files).
    """
    data = study.compute(experiment, designs)
    metrics, files = study.metrics(data), study.write_figures(data, out)
    record = {k: v(data) if callable(v) else v for k, v in record.items()}
    files.append(write_json(out / f"{study.system}_study.json",
                            {"metrics": metrics, "designs": data["params"], **record}))
    return data, metrics, files


def write_json(path: Path, payload: Any) -> Path:
    """``payload`` as indented strict JSON at ``path`` (its directory created; NaN → ``null``, :func:`json_ready`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(json_ready(payload), indent=1, allow_nan=False))
    return path

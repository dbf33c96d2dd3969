"""bibmon's real process data as a labelled table: a plant export, status strings and all, for ``data=table``.

bibmon ships 3,169 rows x 108 anonymised tags of a Petrobras unit at 5-minute steps
(2017-12-24 00:00 to 2018-01-04 00:00, CC-BY-4.0) inside its wheel, which ``pip install
".[te]"`` installs. ``python -m mosd.systems.bibmon_real --export DIR`` writes it as
``DIR/bibmon_real_process_data.csv``: ``time`` (the file's timestamps), ``fault`` (1 from
2018-01-02 06:00 up to, not including, 09:00, the fault bibmon's tutorial scores; 0 elsewhere)
and the tags as bibmon has them: its cells ``Bad``, ``Inp OutRange`` and ``Scan Timeout``
stay text, so that ``data=table`` reads (and counts) them itself, as it must with any export.

The splits. bibmon's tutorial trains from 2017-12-24 12:00 to 2018-01-01, validates to
2018-01-02 and tests to 2018-01-04 (its ``train_val_test_split``: each window ends at its
timestamp, inclusive, and the next starts after it), so the fault lies in its test window
only. mosd's tuning split (``training``) must hold faulty rows (the optimiser minimises FAR
and MDR, and ``RecordedExperiment.prepare`` refuses a training split without one), so the
tutorial's windows verbatim are refused before any work. The command printed keeps the
tutorial's training window as the calibration and lets the tuning split run on from the
tutorial's validation window into the fault's first half (:data:`TUNING_ENDS`); the test
split is the rest: the fault's second half and two days of normal operation. No test row is
tuned on, but both halves are one event: the test MDR says how the tuned design follows the
rest of a fault it has seen the start of, not how it meets a new one (docs/systems/table.md).
"""
from __future__ import annotations

import csv
import importlib.util
from datetime import datetime
from pathlib import Path

from ..validation import ConfigError
from . import cli

#: the exported file's name in the --export folder (its stem names the run: table:bibmon_real_process_data-...)
FILE_NAME = "bibmon_real_process_data.csv"
#: columns the export puts before the tags
TIME, LABEL = "time", "fault"
#: bibmon's tutorial: its training window's start and the ends of its training, validation and test windows
TUTORIAL = {"start": "2017-12-24 12:00:00", "training": "2018-01-01 00:00:00",
            "validation": "2018-01-02 00:00:00", "test": "2018-01-04 00:00:00"}
#: the fault the tutorial scores, [start, end): its comparative_table drops the row at the end time
FAULT = ("2018-01-02 06:00:00", "2018-01-02 09:00:00")
#: where mosd's tuning split ends: halfway through the fault (18 of its 36 rows tuned on, 18 tested)
TUNING_ENDS = "2018-01-02 07:30:00"


def source_file() -> Path:
    """bibmon's ``real_process_data.csv``, found without importing bibmon (its import takes seconds).

    Raises
    ------
    ConfigError
        bibmon is not installed (one line naming the ``te`` extra), or its wheel lacks the file.
    """
    spec = importlib.util.find_spec("bibmon")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError('bibmon\'s real process data needs bibmon: pip install ".[te]"')
    path = Path(list(spec.submodule_search_locations)[0]) / "real_process_data" / "real_process_data.csv"
    if not path.is_file():
        raise ConfigError(f"bibmon at {path.parent.parent} has no real_process_data/real_process_data.csv; "
                          'allowed: bibmon>=1.2 as pip install ".[te]" installs it')
    return path


def _stamp(text: str) -> datetime:
    """A timestamp of bibmon's file (``2018-01-02 06:00:00``) or of this module's constants."""
    return datetime.fromisoformat(text)


def read_source(path: Path) -> tuple[list[str], list[datetime], list[list[str]]]:
    """The tag names, the timestamps and the cells (as text, untouched) of bibmon's file."""
    with path.open(newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader)
        rows = [row for row in reader if row]
    times = [_stamp(row[0]) for row in rows]
    if any(b <= a for a, b in zip(times, times[1:])):  # the windows below are found by time: they need order
        raise ConfigError(f"{path}: the timestamps do not increase; allowed: bibmon's file as its wheel ships it")
    return header[1:], times, [row[1:] for row in rows]


def fault_labels(times: list[datetime]) -> list[int]:
    """1 from the fault's start up to (not including) its end, 0 elsewhere (bibmon's comparative_table)."""
    start, end = (_stamp(t) for t in FAULT)
    return [int(start <= t < end) for t in times]


def tutorial_rows(times: list[datetime]) -> dict[str, tuple[int, int]]:
    """bibmon's tutorial windows as row ranges [start, stop) of the file: training, validation, test."""
    def after(stamp: str) -> int:  # the first row later than ``stamp``: a window ends at its stamp, inclusive
        return next((i for i, t in enumerate(times) if t > _stamp(stamp)), len(times))

    first = next(i for i, t in enumerate(times) if t >= _stamp(TUTORIAL["start"]))
    train, validation, test = after(TUTORIAL["training"]), after(TUTORIAL["validation"]), after(TUTORIAL["test"])
    return {"training": (first, train), "validation": (train, validation), "test": (validation, test)}


def mosd_splits(times: list[datetime]) -> dict[str, tuple[int, int]]:
    """mosd's splits (module docstring): calibration = the tutorial's training window, tuning = its validation
    window and the fault's first half, test = the rest of its test window."""
    windows = tutorial_rows(times)
    tuning_ends = next(i for i, t in enumerate(times) if t >= _stamp(TUNING_ENDS))
    return {"calibration": windows["training"], "training": (windows["validation"][0], tuning_ends),
            "test": (tuning_ends, windows["test"][1])}


def run_command(path: Path, splits: dict[str, tuple[int, int]]) -> str:
    """The ``python -m mosd +experiment=table ...`` line that runs the export with ``splits`` (quoted for a shell:
    an unquoted ``[a,b]`` is a glob pattern)."""
    ranges = " ".join(f"'data.splits.{name}=[{a},{b}]'" for name, (a, b) in splits.items())
    return (f"python -m mosd +experiment=table data.path={path} data.time_column={TIME} "
            f"data.label_column={LABEL} {ranges}")


def export(out_dir: str | Path) -> tuple[Path, dict]:
    """Write ``out_dir/bibmon_real_process_data.csv`` (module docstring); returns its path and what it holds.

    Returns
    -------
    path : Path
    facts : dict
        ``rows``, ``tags``, ``faulty`` (the labelled rows' first and last row numbers and count),
        ``tutorial`` (:func:`tutorial_rows`) and ``splits`` (:func:`mosd_splits`).
    """
    source = source_file()
    tags, times, cells = read_source(source)
    labels = fault_labels(times)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / FILE_NAME
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")  # bibmon's own line ends
        writer.writerow([TIME, LABEL, *tags])
        for stamp, label, row in zip(times, labels, cells):
            writer.writerow([stamp.isoformat(sep=" "), label, *row])
    faulty = [i for i, label in enumerate(labels) if label]
    return path, {"rows": len(times), "tags": len(tags), "faulty": (faulty[0], faulty[-1], len(faulty)),
                  "tutorial": tutorial_rows(times), "splits": mosd_splits(times)}


def main(argv=None) -> int:
    """``python -m mosd.systems.bibmon_real --export DIR``: write the table and print the run's command."""
    parser = cli.ReportParser(prog="python -m mosd.systems.bibmon_real",
                              description="bibmon's real process data (a Petrobras unit) as a labelled table for "
                                          "python -m mosd +experiment=table, and the command that runs it.")
    parser.add_argument("--export", required=True, metavar="DIR", help="the folder to write " + FILE_NAME + " into")

    def body(args):
        path, facts = export(args.export)
        first, last, n = facts["faulty"]
        tutorial, splits = facts["tutorial"], facts["splits"]
        print(f"{path}: {facts['rows']} rows, columns {TIME}, {LABEL} and {facts['tags']} tags (bibmon's status "
              f"strings kept); {LABEL}=1 on rows {first}-{last} ({n} rows, {FAULT[0]} to {FAULT[1][-8:]})")
        print("bibmon's tutorial windows, rows: " + ", ".join(f"{k} {a}-{b - 1}" for k, (a, b) in tutorial.items())
              + f"; its validation window has no faulty row, and mosd tunes on faulty rows (FAR and MDR), so the "
              f"tuning split runs on to {TUNING_ENDS} (the fault's first half) and the test split is the rest")
        print("run next:\n" + run_command(path, splits))
        return [path]

    return cli.run_report(parser, argv, body)


if __name__ == "__main__":
    raise SystemExit(main())

"""The Tennessee Eastman process data of Braatz (Downs & Vogel 1993; Chiang, Russell & Braatz 2001).

The files, as distributed by Braatz and shipped inside the ``bibmon`` wheel:

* 52 variables per sample, one sample every 3 minutes: XMEAS(1)-XMEAS(41)
  (measurements) then XMV(1)-XMV(11) (manipulated variables);
* ``d00.dat``: 500 fault-free samples, stored *transposed* (52 rows of 500 values);
* ``dNN.dat`` (NN = 01..21): 480 samples with fault IDV(NN) active from the first row;
* ``dNN_te.dat`` (NN = 00..21): 960 samples, fault IDV(NN) active from 0-based
  row 160 (8 h into the run; d00_te.dat has no fault).

The files are read from ``directory`` or, when it is not given, from the
installed ``bibmon`` package (``pip install ".[te]"``), located through
``importlib`` without importing ``bibmon`` (its ``__init__`` pulls in optuna,
statsmodels and seaborn). File names are built as ``d{NN:02d}.dat``: bibmon
1.2.0's own loader pads the *training* name after the extension is appended,
so fault 1 becomes ``d10.dat`` (fault 10's data) and faults 3-9 ask for
``d30.dat`` ... ``d90.dat``, which do not exist (docs/systems/tep.md).

Splits (:mod:`mosd.data.base`), all runs 160 rows long except the PCA fit run:

* ``calibration``: ``d00.dat`` (500 rows: the PCA and its theoretical limits),
  then rows 0-159 of ``d02_te.dat``, ``d04_te.dat``, ..., ``d20_te.dat`` (the
  fault-free first 8 h of the even-numbered fault files, held back for the
  empirical and EWMA-recalibrated limits). Not ``d00_te.dat``'s: its rows
  160-959 give the test FAR, and no row of that run calibrates it (issue 49;
  before, its lead-in was an 11th held-back run and set CVA's Q limit);
* ``training``: ``dNN.dat`` of every fault in ``faults`` cut into three runs of
  160 rows, and rows 0-159 of ``d01_te.dat``, ``d03_te.dat``, ..., ``d21_te.dat``
  (fault-free: the FAR the optimiser sees);
* ``test``: rows 160-959 of ``dNN_te.dat`` for every fault in ``test_faults``
  (800 faulty rows each; by default the training faults), then rows 160-959 of
  ``d00_te.dat`` (the literature's FAR). No test row is in any other split,
  and ``d00_te.dat``'s lead-in is in none (scoring streams it as the test
  rows' past only: :func:`mosd.systems.tep.whole_test_files`).
"""
from __future__ import annotations

import functools
import importlib.util
from pathlib import Path
from typing import Sequence

import numpy as np

from ..validation import ConfigError
from .base import RecordedData, Segment, check_names

#: The 52 variable names, in file column order.
VARIABLES = tuple([f"XMEAS({i})" for i in range(1, 42)] + [f"XMV({i})" for i in range(1, 12)])
#: Variable presets: all 52, or the 33 common in the literature (XMEAS 1-22 and XMV 1-11; the
#: analyser measurements XMEAS 23-41 are sampled every 6 or 15 min and held in between).
PRESETS = {"all": VARIABLES, "literature": VARIABLES[:22] + VARIABLES[41:]}
#: Faults the literature reports PCA cannot see (no detectable effect on the measured variables).
UNOBSERVABLE = (3, 9, 15)
#: All 21 process faults IDV(1)..IDV(21).
ALL_FAULTS = tuple(range(1, 22))
DEFAULT_FAULTS = tuple(f for f in ALL_FAULTS if f not in UNOBSERVABLE)
#: 0-based row of the test files from which the fault acts.
ONSET = 160
#: Rows of a training run (the test files' fault-free lead-in; a training file is three of them).
SEGMENT = 160
#: Seconds per sample (3 minutes).
DT = 180.0
#: Rows of each file (what the loader checks).
ROWS = {"train0": 500, "train": 480, "test": 960}


def file_name(fault: int, test: bool = False) -> str:
    """``d01.dat``, ``d01_te.dat``, ...: two digits always (not bibmon's ``d10.dat`` for fault 1)."""
    return f"d{int(fault):02d}{'_te' if test else ''}.dat"


def bibmon_directory() -> Path | None:
    """Where the installed ``bibmon`` keeps its TE files, found without importing ``bibmon``.

    ``importlib.util.find_spec`` locates the package; its loader's resource
    reader (:mod:`importlib.resources`) gives the package's files. None when
    bibmon is not installed.
    """
    try:
        spec = importlib.util.find_spec("bibmon")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    reader = spec.loader.get_resource_reader("bibmon") if hasattr(spec.loader, "get_resource_reader") else None
    root = Path(str(reader.files())) if reader is not None else Path(list(spec.submodule_search_locations)[0])
    folder = root / "tennessee_eastman"
    return folder if folder.is_dir() else None


@functools.lru_cache(maxsize=64)
def _read(path: str, mtime: float) -> np.ndarray:
    data = np.loadtxt(path, dtype=float, ndmin=2)
    data.setflags(write=False)
    return data


def read_file(path: Path) -> np.ndarray:
    """One Braatz file as (rows, 52), d00.dat's 52 x 500 transposed (cached while the file is unchanged)."""
    try:
        data = _read(str(path), path.stat().st_mtime)
    except FileNotFoundError:
        raise ConfigError(f"data.directory: {path.name} is missing in {path.parent}; allowed: a directory with "
                          "the Braatz files d00.dat ... d21.dat and d00_te.dat ... d21_te.dat") from None
    except ValueError as exc:
        raise ConfigError(f"data.directory: {path} is not a table of numbers ({exc}); allowed: the Braatz "
                          "files (whitespace-separated numbers)") from None
    if data.shape[0] == len(VARIABLES) and data.shape[1] != len(VARIABLES):
        data = data.T  # d00.dat is stored one variable per row
    if data.shape[1] != len(VARIABLES):
        raise ConfigError(f"data.directory: {path} has {data.shape[1]} columns; allowed: 52 (XMEAS 1-41, XMV 1-11)")
    return data


class TennesseeEastman(RecordedData):
    """The Braatz TE data as calibration, training and test splits (module docstring).

    Parameters
    ----------
    directory : str, optional
        A folder with d00.dat ... d21_te.dat; None reads the installed bibmon's copy.
    variables : str or sequence of str
        ``"literature"`` (33: XMEAS 1-22, XMV 1-11), ``"all"`` (52), or names such as
        ``["XMEAS(1)", "XMV(10)"]``.
    faults : sequence of int
        The faults of the training split (IDV numbers 1..21); default all but 3, 9 and 15.
    test_faults : sequence of int, optional
        The faults of the test split; default (None) those of ``faults``, so that the run's test
        metrics measure what was tuned. The TE study reports all 21 regardless (:mod:`mosd.systems.tep`).
    """

    dt = DT
    fault_names = tuple(f"IDV({i})" for i in ALL_FAULTS)

    def __init__(self, directory: str | None = None, variables: str | Sequence[str] = "literature",
                 faults: Sequence[int] = DEFAULT_FAULTS, test_faults: Sequence[int] | None = None):
        if isinstance(variables, str):
            if variables not in PRESETS:
                raise ConfigError(f"data.variables={variables!r} is not a preset; allowed: {', '.join(PRESETS)} "
                                  "or a list of names such as [XMEAS(1), XMV(10)]")
            self.variables = variables
            names = PRESETS[variables]
        else:
            names = check_names("data.variables", variables, VARIABLES)
            self.variables = list(names)
        self.output_names = tuple(names)
        self._columns = np.array([VARIABLES.index(n) for n in names])
        self.faults = _check_faults("data.faults", faults)
        self.test_faults = self.faults if test_faults is None else _check_faults("data.test_faults", test_faults)
        if directory is None:
            found = bibmon_directory()
            if found is None:
                raise ConfigError('data=tep needs the Tennessee Eastman files: pip install ".[te]" (the bibmon '
                                  "package ships them), or data.directory=DIR with d00.dat ... d21_te.dat")
            self.directory = None
            self.path = found
        else:
            self.directory = str(directory)
            self.path = Path(directory).expanduser()
            if not self.path.is_dir():
                raise ConfigError(f"data.directory={directory!r} is not a directory; allowed: a folder with the "
                                  "Braatz files d00.dat ... d21_te.dat")
        self.check_disjoint()

    def __repr__(self) -> str:
        where = self.directory or "bibmon"
        return f"TennesseeEastman({where}, {len(self.output_names)} variables, faults {list(self.faults)})"

    def raw(self, name: str) -> np.ndarray:
        """All 52 columns of one file (rows, 52); the row count is checked against the Braatz layout."""
        data = read_file(self.path / name)
        expected = ROWS["test"] if name.endswith("_te.dat") else ROWS["train0" if name == "d00.dat" else "train"]
        if data.shape[0] != expected:
            raise ConfigError(f"data.directory: {self.path / name} has {data.shape[0]} rows; allowed: {expected} "
                              "(the Braatz layout)")
        return data

    def values(self, source: str) -> np.ndarray:
        return self.raw(source)[:, self._columns]

    def segments(self, split: str) -> list[Segment]:
        if split == "calibration":
            # the even fault files' lead-ins; not d00_te.dat's, whose later rows measure the test FAR (docstring)
            held = [Segment(file_name(i, test=True), 0, ONSET) for i in range(2, 22, 2)]
            return [Segment("d00.dat", 0, ROWS["train0"]), *held]
        if split == "training":
            faulty = [Segment(file_name(f), s, s + SEGMENT, label=f, onset=0)
                      for f in self.faults for s in range(0, ROWS["train"], SEGMENT)]
            return faulty + [Segment(file_name(i, test=True), 0, ONSET) for i in range(1, 22, 2)]
        if split == "test":
            faulty = [Segment(file_name(f, test=True), ONSET, ROWS["test"], label=f, onset=ONSET)
                      for f in self.test_faults]
            return faulty + [Segment(file_name(0, test=True), ONSET, ROWS["test"])]
        return []


def _check_faults(key: str, faults: Sequence[int]) -> tuple[int, ...]:
    if isinstance(faults, (int, np.integer)):
        faults = [faults]
    values = []
    for f in faults:
        try:
            ok = float(f).is_integer() and 1 <= int(f) <= 21
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ConfigError(f"{key}: {f!r} is not a TE fault; allowed: integers 1..21 (IDV numbers)")
        values.append(int(f))
    if not values or len(set(values)) != len(values):
        raise ConfigError(f"{key}={list(faults)} is not a set of faults; allowed: distinct integers 1..21")
    return tuple(values)

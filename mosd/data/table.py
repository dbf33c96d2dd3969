"""Any labelled table (CSV or Parquet) as recorded data: a historian export, a lab log, a benchmark.

The table has one row per sample, an optional time column, an optional label
column (the fault id: 0, empty or missing = normal operation) and the tag
columns to monitor. Splits are row ranges (fractions of the rows, or row
numbers) taken in time order, one run per split.

Historian error codes. Exports put strings such as ``Inp OutRange``, ``Bad``
or ``Scan Timeout`` into numeric columns (and some a number such as ``1e308`` or
``-1.7e308``: any cell beyond ±:data:`MAX_ABS` is taken as such a code, since
its square, in the variance and the statistics, would overflow). With ``errors="strict"`` the first
such cell stops the run with one line naming the file, the column, the row
and the text. With ``errors="nan"`` (the default) every cell that is not a
number becomes missing, and ``fill`` decides what happens next:

* ``hold``: the last valid value is carried forward (a historian's own
  convention; leading gaps take the first valid value);
* ``interpolate``: linear in the row number between the valid neighbours
  (held at the ends);
* ``drop``: rows with any missing tag are removed (the splits are fractions of the rows kept; what is
  recorded of them, in ``summary.json`` and the test stream, is the file's rows and the file's clock);
* ``none``: left missing (a PCA detector skips incomplete rows: no alarm there).

A tag that is constant over the calibration rows (after filling) carries no
information and would break the standardisation: it is dropped with a warning.
Rows labelled faulty inside the calibration range are left out of it (the
calibration is fault-free by definition).

What is checked before any work (one line each, naming the file, the row and the value):

* the time column parses (every cell a timestamp, or every cell a number of seconds) and
  strictly increases: a shuffled export would give a wrong sample step, hence wrong delays,
  reported as right. ``sort=True`` sorts the rows by time instead, and says so on stdout;
  a repeated time is refused either way;
* every label is a fault id: an integer in 0..:data:`MAX_LABEL` (0 or empty = normal);
* the table has data rows, and every split at least :data:`MIN_SPLIT_ROWS` of them;
* the calibration has more fault-free rows than tags (:data:`MIN_ROWS_PER_TAG`): with
  ``n <= m`` rows for ``m`` tags the sample covariance is singular (rank ``n - 1 < m``), the
  residual space of the PCA is not estimated at all and the SPE limit built from its
  eigenvalues (Jackson & Mudholkar 1979) is too low: the monitor's limits cannot be trusted
  (a 600-row calibration of 1,994 tags gave a test false-alarm rate of 0.73). Below
  :data:`WARN_ROWS_PER_TAG` rows per tag the run goes on with a one-line warning
  (docs/systems/tep.md, "How many calibration rows").
"""
from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..types import Trace
from ..validation import ConfigError, check_choice
from .base import SPLITS, RecordedData, Segment, without_labelled_rows

log = logging.getLogger("mosd.data")

ERRORS = ("strict", "nan")
FILLS = ("hold", "interpolate", "drop", "none")
DEFAULT_SPLITS = {"calibration": [0.0, 0.5], "training": [0.5, 0.75], "test": [0.75, 1.0]}
#: rows every split needs: a split of one row has no step, no spread and no run to score
MIN_SPLIT_ROWS = 2
#: fault-free calibration rows per tag below which the run is refused (n <= m: singular covariance)
MIN_ROWS_PER_TAG = 1
#: ... and below which it warns (module docstring; docs/systems/tep.md)
WARN_ROWS_PER_TAG = 5
#: a cell beyond ±MAX_ABS is an error code, not a measurement: its square (the variance, T², SPE) would overflow
MAX_ABS = 1e150
#: the largest fault id a label may hold: recorded-data traces keep their labels as int16 (mosd.data.base), and
#: a larger one was cast to a negative id (1e30: counted as faulty, neither normal nor any fault) or made a
#: name per id up to it (1,000,000,000: out of memory)
MAX_LABEL = int(np.iinfo(np.int16).max)


class Table(RecordedData):
    """A CSV or Parquet table as calibration, training and test splits (module docstring).

    Parameters
    ----------
    path : str
        A ``.csv`` (or ``.csv.gz``) or ``.parquet`` file.
    time_column : str or int or False, optional
        The time column (name, or 0-based position); sets ``dt`` from the median step.
        None: the one column whose every cell is a timestamp, said on stdout (none or several: the
        samples are numbered and ``dt`` is taken from ``dt``); False: samples numbered, no detection.
    label_column : str, optional
        The fault id per row (0, empty = normal); None: every row is normal operation.
    tags : "all" or sequence of str
        The columns to monitor ("all": every column but the time and label columns).
    errors : {"nan", "strict"}
        What a non-numeric cell in a tag column is (module docstring).
    fill : {"hold", "interpolate", "drop", "none"}
        What becomes of missing values (module docstring).
    splits : mapping
        ``{calibration: [start, stop], training: [...], test: [...]}``: fractions of the rows
        (numbers in [0, 1]) or row numbers (stop exclusive); disjoint.
    dt : float
        Seconds per sample when there is no time column.
    sort : bool
        Sort the rows by the time column (stable) instead of refusing a time that goes back;
        the number of rows out of order is printed on stdout.
    """

    def __init__(self, path: str | None = None, time_column: str | int | bool | None = None, label_column: str | None = None,
                 tags: str | Sequence[str] = "all", errors: str = "nan", fill: str = "hold",
                 splits: Mapping[str, Sequence[float]] | None = None, dt: float = 1.0, sort: bool = False):
        if path is None or str(path) in ("", "???"):
            raise ConfigError("data.path is not set; allowed: a .csv or .parquet file (data.path=FILE)")
        self.path = str(path)
        self.errors = check_choice("data.errors", errors, ERRORS)
        self.fill = check_choice("data.fill", fill, FILLS)
        if not isinstance(sort, bool):
            raise ConfigError(f"data.sort={sort!r} is not allowed; allowed: true, false")
        self.time_column, self.label_column, self.sort = time_column, label_column, sort
        self._order = None  # data.sort=true: the file's data-row number of each row in time order
        frame = _read(Path(self.path).expanduser())
        columns = [str(c) for c in frame.columns]
        frame.columns = columns
        if len(frame) < len(SPLITS) * MIN_SPLIT_ROWS:
            what = "a header and no data row" if len(frame) == 0 else f"{len(frame)} data row{'s' * (len(frame) > 1)}"
            raise ConfigError(f"data.path={self.path!r} has {what}; allowed: a table with at least "
                              f"{len(SPLITS) * MIN_SPLIT_ROWS} rows ({MIN_SPLIT_ROWS} per split: "
                              f"{', '.join(SPLITS)})")
        if time_column is not False and not (isinstance(time_column, str) and time_column.lower() in ("false", "none")):
            time_name = self._column("data.time_column", time_column, columns) if time_column is not None else None
        else:
            time_name, time_column = None, False
        label_name = self._column("data.label_column", label_column, columns) if label_column is not None else None
        seconds = None
        if time_column is None:
            time_name, seconds = self._detected_time(frame, columns, label_name)
        elif time_name:
            seconds = self._seconds(frame[time_name], time_name)
        if time_name:
            frame, seconds = self._in_time_order(frame, seconds, time_name)
        reserved = {time_name, label_name}
        if isinstance(tags, str):
            if tags != "all":
                raise ConfigError(f"data.tags={tags!r} is not allowed; allowed: all, or a list of column names")
            names = [c for c in columns if c not in reserved]
        else:
            names = [self._column("data.tags", t, columns) for t in tags]
            if len(set(names)) != len(names):
                raise ConfigError("data.tags names a column twice; allowed: distinct column names")
        if not names:
            raise ConfigError(f"data.tags selects no column of {self.path}; allowed: column names besides the "
                              "time and label columns")
        self._not_numbers = {}  # tag -> counts of its texts read as missing (_numeric): said in one line
        values = np.column_stack([self._numeric(frame[name], name) for name in names])
        self._say_not_numbers()
        labels = self._labels(frame[label_name], label_name) if label_name else np.zeros(len(frame), int)
        self.dt = float(np.median(np.diff(seconds))) if time_name else _positive("data.dt", dt)
        values, labels, kept = _fill(values, labels, self.fill)
        # what is recorded of a row is the file's: its data-row number and its time on the file's clock (seconds
        # from the first row; row x dt without a time column), whatever rows data.fill=drop left out before it
        self._rows = kept if self._order is None else self._order[kept]
        self._times = seconds[kept] if time_name else self._rows * self.dt
        self._ranges = self._split_ranges(splits or DEFAULT_SPLITS, len(values))
        calibration = slice(*self._ranges["calibration"])
        normal = labels[calibration] == 0
        for split, (start, stop) in self._ranges.items():
            if not np.any(labels[start:stop] == 0):
                raise ConfigError(f"data.splits.{split}: rows {start}-{stop - 1} of {self.path} have no fault-free "
                                  f"row (column {label_name!r}); allowed: a range with normal rows (label 0 or empty)")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an all-missing column: NaN, constant-by-absence
            reference = values[calibration][normal]
            spread = np.nanstd(reference, axis=0, ddof=1)
            level = np.nanmean(np.abs(reference), axis=0)
        # relative to the tag's own level: the std of a constant 0.0888 comes out as 1e-17, not 0, while a tag in
        # units of 1e-14 varies by 1e-14 (issue 53: an absolute floor of 1e-12 called it constant and dropped it)
        constant = ~(spread > 1e-12 * level)
        if constant.all():
            raise ConfigError(f"data.tags: every tag of {self.path} is constant over the calibration rows; "
                              "allowed: tags that vary")
        if constant.any():
            dropped = [n for n, c in zip(names, constant) if c]
            # one line (a logged warning: warnings.warn would add the caller's file, line and source)
            log.warning(f"data: {len(dropped)} tags of {self.path} are constant over the calibration rows, dropped: "
                        + ", ".join(dropped))
        self.dropped = tuple(n for n, c in zip(names, constant) if c)
        self.output_names = tuple(n for n, c in zip(names, constant) if not c)
        self._check_rows_per_tag(values[calibration][normal][:, ~constant])
        self._values = values[:, ~constant]
        self._labels = labels
        n_faults = int(labels.max()) if labels.size else 0
        self.fault_names = tuple(f"label {i}" for i in range(1, n_faults + 1))
        self.check_disjoint()

    def __repr__(self) -> str:
        return f"Table({self.path}, {len(self.output_names)} tags, {len(self._values)} rows)"

    # -- reading ---------------------------------------------------------------------------
    def _column(self, key: str, name, columns: list[str]) -> str:
        if isinstance(name, int) and not isinstance(name, bool):
            if not 0 <= name < len(columns):
                raise ConfigError(f"{key}={name} is not a column position of {self.path}; "
                                  f"allowed: 0..{len(columns) - 1}")
            return columns[name]
        if str(name) not in columns:
            shown = ", ".join(columns[:8]) + (", ..." if len(columns) > 8 else "")
            raise ConfigError(f"{key}: column {name!r} is not in {self.path}; allowed: {shown}")
        return str(name)

    def _numeric(self, column, name: str) -> np.ndarray:
        import pandas as pd

        if pd.api.types.is_numeric_dtype(column.dtype) and not pd.api.types.is_bool_dtype(column.dtype):
            numbers = column.to_numpy(dtype=float, na_value=np.nan)
            bad = np.abs(numbers) > MAX_ABS
        else:
            converted = pd.to_numeric(column, errors="coerce")
            text = column.astype("string").str.strip()
            numbers = converted.to_numpy(dtype=float, na_value=np.nan)
            bad = (converted.isna() & column.notna() & (text != "")).to_numpy(dtype=bool) | (np.abs(numbers) > MAX_ABS)
        if bad.any() and self.errors == "strict":
            row = int(np.flatnonzero(bad)[0])
            raise ConfigError(f"{self.path}: column {name!r} row {self._file_row(row)} holds "
                              f"{str(column.iloc[row])!r}, not a number within ±{MAX_ABS:g}; allowed: numbers "
                              "(data.errors=nan reads historian error codes and such values as missing values)")
        if bad.any():
            numbers = np.where(bad, np.nan, numbers)
            # counted, not only replaced: a status code read as missing is said on stdout (_say_not_numbers)
            self._not_numbers[name] = column.iloc[np.flatnonzero(bad)].astype("string").str.strip().value_counts()
        return numbers

    def _say_not_numbers(self, shown: int = 5) -> None:
        """One stdout line: the cells that were not numbers, per tag (most first, ``shown`` of them) and their
        texts, e.g. ``data: 498 cells of plant.csv were not numbers (read as missing; data.fill=hold): tag70
        326 "Bad", ...``; nothing when every cell was a number."""
        if not self._not_numbers:
            return
        counts = sorted(self._not_numbers.items(), key=lambda item: -int(item[1].sum()))
        total = sum(int(c.sum()) for _, c in counts)
        parts = []
        for name, texts in counts[:shown]:
            said = ", ".join(f'"{t}" {n}' for t, n in texts.iloc[:2].items())
            said = f'"{texts.index[0]}"' if len(texts) == 1 else f"({said}{', ...' * (len(texts) > 2)})"
            parts.append(f"{name} {int(texts.sum())} {said}")
        if len(counts) > shown:
            parts.append(f"{len(counts) - shown} more tags {sum(int(c.sum()) for _, c in counts[shown:])}")
        print(f"data: {total} cells of {self.path} were not numbers (read as missing; data.fill={self.fill}): "
              + ", ".join(parts))

    def _labels(self, column, name: str) -> np.ndarray:
        import pandas as pd

        numbers = pd.to_numeric(column, errors="coerce")
        text = column.astype("string").str.strip()
        # checked as floats before any cast: an integral 1e30 passes `% 1` and casts to int64's minimum
        values = numbers.to_numpy(dtype=float, na_value=np.nan)
        with np.errstate(invalid="ignore"):  # inf % 1 is NaN: not an integer, refused below
            fractional = np.isfinite(values) & (values % 1 != 0)
        out_of_range = ~np.isnan(values) & ~((values >= 0) & (values <= MAX_LABEL))
        bad = (numbers.isna() & column.notna() & (text != "")).to_numpy(dtype=bool) | fractional | out_of_range
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise ConfigError(f"data.label_column={name!r}: {self.path}: column {name!r} row {self._file_row(row)} "
                              f"holds {str(column.iloc[row])!r}, not a fault id; allowed: integers 0..{MAX_LABEL} "
                              "(0 or empty = normal)")
        return np.nan_to_num(values, nan=0.0).astype(np.int64)

    def _seconds(self, column, name: str) -> np.ndarray:
        """The time column as seconds from its first row: numbers as they are, or timestamps (one line naming
        the first cell that is neither)."""
        import pandas as pd

        allowed = "allowed: timestamps in one format (as pandas.to_datetime reads them) or numbers (seconds)"
        if pd.api.types.is_numeric_dtype(column.dtype) and not pd.api.types.is_bool_dtype(column.dtype):
            seconds = column.to_numpy(dtype=float, na_value=np.nan)
            bad = ~np.isfinite(seconds)
        elif pd.api.types.is_datetime64_any_dtype(column.dtype):
            bad = column.isna().to_numpy()
            seconds = (column - column[~bad].iloc[0]).dt.total_seconds().to_numpy() if not bad.all() else None
        else:
            with warnings.catch_warnings():
                # pandas' "could not infer format" advice: the format is the first cell's, every cell is checked
                warnings.simplefilter("ignore", UserWarning)
                try:
                    stamps = pd.to_datetime(column, errors="coerce")
                except (ValueError, TypeError, OverflowError):  # mixed time zones, and the like
                    stamps = _offset_stamps(column)
            bad = stamps.isna().to_numpy()
            seconds = None
            if not bad.all():
                try:
                    seconds = (stamps - stamps[~bad].iloc[0]).dt.total_seconds().to_numpy()
                except (TypeError, AttributeError):  # time zones mixed with naive stamps: not one clock
                    bad = np.ones(len(column), bool)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            value = column.iloc[row]
            shown = "an empty cell" if value is None or (isinstance(value, float) and np.isnan(value)) \
                or str(value).strip() in ("", "NaT", "nan") else repr(str(value))
            raise ConfigError(f"{self.path}: column {name!r} row {row} holds {shown}, not a time; {allowed}")
        return np.asarray(seconds, float)

    def _detected_time(self, frame, columns: list[str], label_name: str | None):
        """(name, seconds) of the one column whose every cell is a timestamp, in strictly increasing time (in any
        order with ``sort``), when ``time_column`` is not set; said in one line. (None, None) when no column, or
        more than one, is: the rows are then numbered, as before the detection."""
        import pandas as pd

        found = []
        for name in columns:
            column = frame[name]
            text = column.dtype == object or pd.api.types.is_string_dtype(column.dtype)
            if name == label_name or not (text or pd.api.types.is_datetime64_any_dtype(column.dtype)):
                continue
            head = column.dropna().head(5).astype(str)
            if head.empty or not pd.to_numeric(head, errors="coerce").isna().all():
                continue  # numbers in text (a tag with an error code) are not times
            try:
                seconds = self._seconds(column, name)
            except ConfigError:
                continue
            if not self.sort and not np.all(np.diff(seconds) > 0):
                continue  # not this table's clock (a date per batch, a shuffled export): a named column is refused
            found.append((name, seconds))
        if len(found) != 1:
            return None, None
        name, seconds = found[0]
        self.time_column = name
        print(f"data: column {name!r} holds a timestamp on every row: used as data.time_column "
              "(data.time_column=false numbers the rows instead)", flush=True)
        return name, seconds

    def _in_time_order(self, frame, seconds: np.ndarray, name: str):
        """The frame in strictly increasing time: as it is, or sorted when ``sort`` is set (said on stdout)."""
        steps = np.diff(seconds)
        if np.all(steps > 0):
            return frame, seconds
        if self.sort:
            order = np.argsort(seconds, kind="stable")
            self._order = order
            moved = int(np.count_nonzero(order != np.arange(len(order))))
            frame, seconds = frame.iloc[order].reset_index(drop=True), seconds[order]
            if moved:
                print(f"data: {moved} of {len(order)} rows of {self.path} were out of time order; sorted by "
                      f"column {name!r} (data.sort=true)")
            steps = np.diff(seconds)
            if np.all(steps > 0):
                return frame, seconds
        row = int(np.flatnonzero(steps <= 0)[0]) + 1
        if steps[row - 1] == 0:
            raise ConfigError(f"{self.path}: column {name!r} row {row} repeats the time of row {row - 1} "
                              f"({frame[name].iloc[row]!r}); allowed: one row per time")
        if not np.all(steps > 0):
            raise ConfigError(f"{self.path}: column {name!r} goes back at row {row} ({frame[name].iloc[row]!r} after "
                              f"{frame[name].iloc[row - 1]!r}); allowed: strictly increasing time, or data.sort=true "
                              "to sort the rows by time")
        return frame, seconds

    def _check_rows_per_tag(self, calibration: np.ndarray) -> None:
        """Refuse a calibration with no more fault-free rows than tags, warn below WARN_ROWS_PER_TAG per tag."""
        rows, tags = int(np.count_nonzero(np.all(np.isfinite(calibration), axis=1))), calibration.shape[1]
        where = f"data.splits.calibration: {rows} fault-free complete rows of {self.path} for {tags} tags"
        if rows <= MIN_ROWS_PER_TAG * tags:
            raise ConfigError(f"{where}: the covariance is singular and the monitor's limits cannot be trusted; "
                              f"allowed: more calibration rows than tags (a longer data.splits.calibration, or "
                              f"fewer data.tags; {WARN_ROWS_PER_TAG} rows per tag or more to trust the limits)")
        if rows < WARN_ROWS_PER_TAG * tags:
            message = (f"{where} (fewer than {WARN_ROWS_PER_TAG} per tag): the monitor's limits are estimated "
                       f"loosely and the false-alarm rate may exceed its target (docs/systems/tep.md)")
            log.warning(message)  # one line

    def _split_ranges(self, splits: Mapping[str, Sequence[float]], n_rows: int) -> dict[str, tuple[int, int]]:
        unknown = set(splits) - set(SPLITS)
        if unknown:
            raise ConfigError(f"data.splits.{sorted(unknown)[0]} is not a split; allowed: {', '.join(SPLITS)}")
        ranges = {}
        for split in SPLITS:
            pair = splits.get(split)
            if pair is None or len(pair) != 2:
                raise ConfigError(f"data.splits.{split}={pair!r} is not a range; allowed: [start, stop] as fractions "
                                  "of the rows or row numbers")
            lo, hi = (float(v) for v in pair)
            if 0.0 <= lo <= 1.0 and 0.0 <= hi <= 1.0 and not (lo.is_integer() and hi.is_integer() and hi > 1):
                start, stop = int(round(lo * n_rows)), int(round(hi * n_rows))
            else:
                start, stop = int(lo), int(hi)
            if not 0 <= start < stop <= n_rows:
                raise ConfigError(f"data.splits.{split}={list(pair)} gives rows {start}-{stop - 1} of {n_rows}; "
                                  f"allowed: a non-empty range within 0..{n_rows}")
            if stop - start < MIN_SPLIT_ROWS:
                raise ConfigError(f"data.splits.{split}={list(pair)} gives {stop - start} row (row {start}) of "
                                  f"{n_rows}; allowed: at least {MIN_SPLIT_ROWS} rows per split")
            ranges[split] = (start, stop)
        return ranges

    # -- the contract ----------------------------------------------------------------------
    def values(self, source: str) -> np.ndarray:
        return self._values

    def segments(self, split: str) -> list[Segment]:
        start, stop = self._ranges[split]
        first, last = self.file_rows(split)
        return [TableSegment(self.path, start, stop, labels=self._labels[start:stop], first_row=first, last_row=last,
                             dropped=last - first + 1 - (stop - start) if self._order is None else 0)]

    def trace(self, split: str) -> Trace:
        """As :meth:`RecordedData.trace`, on the file's clock; the calibration's labelled rows are left out (set
        missing)."""
        from dataclasses import replace

        start, stop = self._ranges[split]
        # the rows' own times: k x dt from the split's start was off wherever data.fill=drop left rows out
        trace = replace(super().trace(split), t=np.asarray(self._times[start:stop], float))
        return without_labelled_rows(trace) if split == "calibration" else trace

    def file_rows(self, split: str) -> tuple[int, int]:
        """The first and last data row of the file a split covers (after ``fill="drop"``)."""
        start, stop = self._ranges[split]
        return int(self._rows[start]), int(self._rows[stop - 1])

    def _file_row(self, row: int) -> int:
        """The file's data-row number of row ``row`` of the table as read (in time order under data.sort=true)."""
        return int(self._order[row]) if self._order is not None else int(row)


@dataclass(frozen=True)
class TableSegment(Segment):
    """A table's split: ``start``/``stop`` count the rows kept (:meth:`Table.values`), ``first_row``..``last_row``
    are the file's data rows it covers, of which ``dropped`` were left out (``data.fill=drop``)."""

    first_row: int = 0
    last_row: int = 0
    dropped: int = 0

    def describe(self) -> str:
        """``plant.csv rows 900-1199 (75 rows with a missing tag dropped; 87 labelled faulty)``: the file's rows."""
        notes = [f"{self.dropped} rows with a missing tag dropped by data.fill=drop"] if self.dropped else []
        notes.append(f"{int(np.count_nonzero(self.row_labels()))} labelled faulty")
        return f"{self.source} rows {self.first_row}-{self.last_row} ({'; '.join(notes)})"


def _read(path: Path):
    """A pandas DataFrame from a CSV or Parquet file (one-line errors)."""
    try:
        import pandas as pd
    except ImportError:
        raise ConfigError('data=table needs pandas, a dependency of mosd: pip install "pandas>=2.0"') from None
    if not path.is_file():
        raise ConfigError(f"data.path={str(path)!r}: no such file; allowed: a .csv or .parquet file")
    suffixes = "".join(path.suffixes[-2:]).lower()
    try:
        if path.suffix.lower() in (".parquet", ".pq"):
            try:
                import pyarrow  # noqa: F401
            except ImportError:
                raise ConfigError('data=table needs pyarrow for Parquet files, a dependency of mosd: '
                                  'pip install "pyarrow>=14"') from None
            return pd.read_parquet(path)
        if path.suffix.lower() == ".csv" or suffixes.endswith((".csv.gz", ".csv.bz2", ".csv.zip")):
            # the header first: a refused file is not read whole
            _check_unique_header(pd.read_csv(path, header=None, nrows=1, dtype=str).iloc[0].tolist(), path)
            return pd.read_csv(path)
    except ConfigError:
        raise
    except Exception as exc:
        raise ConfigError(f"data.path={str(path)!r} cannot be read: {type(exc).__name__}: "
                          f"{' '.join(str(exc).split())}") from None
    raise ConfigError(f"data.path={str(path)!r} is neither CSV nor Parquet; allowed: .csv, .csv.gz, .parquet")


#: an ISO-8601 time's UTC offset at its end: Z, +01:00, -0500
_OFFSET = r"(?:Z|[+-]\d{2}:?\d{2})$"


def _offset_stamps(column):
    """Timestamps whose UTC offsets differ from row to row (a DST change: +01:00, then +02:00) on one clock, UTC.

    pandas refuses a column of mixed offsets unless told to convert to UTC; that is right only when every stamp
    carries its offset (a naive stamp's zone is unknown), so a column mixing both stays unparsed (refused).
    """
    import pandas as pd

    text = column.astype("string").str.strip()
    given = text.notna() & (text != "")
    if not text[given].str.contains(_OFFSET, regex=True).all():
        return pd.Series(pd.NaT, index=column.index)
    try:
        return pd.to_datetime(column, errors="coerce", utc=True, format="ISO8601")
    except (ValueError, TypeError, OverflowError):
        return pd.Series(pd.NaT, index=column.index)


def _check_unique_header(names: list, path: Path) -> None:
    """A column named twice is refused: pandas would rename the second ``TI-0.1`` and run it as another tag."""
    seen: set = set()
    for position, name in enumerate(names):
        if not isinstance(name, str):  # an empty cell: pandas names it "Unnamed: N", unique by position
            continue
        if name in seen:
            raise ConfigError(f"data.path={str(path)!r}: column {name!r} is named twice (again at position {position}); "
                              "allowed: a header whose column names are unique")
        seen.add(name)


def _fill(values: np.ndarray, labels: np.ndarray, fill: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Apply the missing-value policy; returns values, labels and the kept rows' numbers."""
    rows = np.arange(len(values))
    missing = ~np.isfinite(values)
    if fill == "none" or not missing.any():
        return values, labels, rows
    if fill == "drop":
        keep = ~missing.any(axis=1)
        return values[keep], labels[keep], rows[keep]
    out = values.copy()
    for j in np.flatnonzero(missing.any(axis=0)):
        good = ~missing[:, j]
        if not good.any():
            continue  # an empty column stays missing; it is constant-by-absence and dropped later
        if fill == "hold":
            # index of the last valid row at or before each row (the first valid one before any)
            last = np.maximum.accumulate(np.where(good, rows, -1))
            last = np.where(last < 0, np.flatnonzero(good)[0], last)
            out[:, j] = values[last, j]
        else:
            out[:, j] = np.interp(rows, rows[good], values[good, j])
    return out, labels, rows


def _positive(key: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not v > 0:
        raise ConfigError(f"{key}={value!r} is not allowed; allowed: a number > 0 (seconds per sample)")
    return v

"""SKAB, the Skoltech Anomaly Benchmark (github.com/waico/SKAB, GPL-3.0): read a folder of its layout.

SKAB records a water-circulation testbed (pump, valves, tank) with 8 sensors
sampled about once a second. mosd never ships the files (their licence is
GPL-3.0): users clone that repository and point ``root`` at its ``data/``
folder, which holds

* ``valve1/0.csv`` ... ``valve1/15.csv``: the valve at the pump's inlet closed;
* ``valve2/0.csv`` ... ``valve2/3.csv``: the valve at the pump's outlet closed;
* ``other/1.csv`` ... ``other/14.csv``: leaks, rotor imbalance, cavitation, ...;
* ``anomaly-free/anomaly-free.csv``: normal operation only, without label columns.

Each file is ``;``-separated with a ``datetime`` column, the 8 sensor columns
of :data:`TAGS` and, in the 34 experiments with anomalies, the labels
``anomaly`` and ``changepoint`` (0/1). SKAB's protocol: the first
:data:`FIT_ROWS` rows of each experiment are its fit part, the rest its test
part. The benchmark says the fit part holds no anomaly; ``other/2.csv`` has
296 rows labelled anomalous among its first 400 (commit b2c0d46), so the
labels are returned as they are and :attr:`SkabExperiment.fit_anomalies`
counts such rows: what a caller does with them is its own protocol's choice.

:func:`read_experiments` and :func:`read_anomaly_free` return
:class:`SkabExperiment` records; :class:`Skab` (the Hydra data source,
``data=skab``, below) builds on them. Bad input is one
:class:`~mosd.validation.ConfigError` line naming the path, the key and what is
allowed.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..types import Trace
from ..validation import ConfigError
from .base import RecordedData, Segment, without_labelled_rows

#: The 8 sensor columns, in file order.
TAGS = ("Accelerometer1RMS", "Accelerometer2RMS", "Current", "Pressure", "Temperature", "Thermocouple",
        "Voltage", "Volume Flow RateRMS")
#: The label columns of an experiment with anomalies.
LABELS = ("anomaly", "changepoint")
TIME = "datetime"
#: The folders with anomalies, in the benchmark's order.
ANOMALY_GROUPS = ("valve1", "valve2", "other")
FREE = "anomaly-free"
GROUPS = (*ANOMALY_GROUPS, FREE)
#: SKAB's fit part: the first 400 rows of each experiment.
FIT_ROWS = 400
SEP = ";"


@dataclass(frozen=True, eq=False)
class SkabExperiment:
    """One SKAB recording (module docstring).

    Attributes
    ----------
    group : str
        The folder: ``valve1``, ``valve2``, ``other`` or ``anomaly-free``.
    name : str
        ``valve1/3``: the folder and the file's stem.
    time : ndarray of datetime64[s]
        The ``datetime`` column (strictly increasing).
    values : ndarray of float, shape (rows, 8)
        The sensor columns in :data:`tags` order.
    tags : tuple of str
    anomaly, changepoint : ndarray of bool, shape (rows,)
        The labels (all False in ``anomaly-free``, which has none).
    fit_rows : int
        Rows ``0 .. fit_rows-1`` are the fit part (SKAB's 400; every row of ``anomaly-free``).
    """

    group: str
    name: str
    time: np.ndarray
    values: np.ndarray
    tags: tuple[str, ...]
    anomaly: np.ndarray
    changepoint: np.ndarray
    fit_rows: int = FIT_ROWS

    @property
    def n_rows(self) -> int:
        return int(self.values.shape[0])

    @property
    def seconds(self) -> np.ndarray:
        """Seconds from the first row (float)."""
        return (self.time - self.time[0]).astype("timedelta64[s]").astype(float)

    @property
    def fit_anomalies(self) -> int:
        """Rows of the fit part labelled anomalous (module docstring: ``other/2`` has 296)."""
        return int(np.count_nonzero(self.anomaly[: self.fit_rows]))

    def fit(self) -> np.ndarray:
        """The fit part's values, shape (fit_rows, 8)."""
        return self.values[: self.fit_rows]

    def test(self) -> tuple[np.ndarray, np.ndarray]:
        """The test part: values (rows - fit_rows, 8) and the anomaly labels."""
        return self.values[self.fit_rows:], self.anomaly[self.fit_rows:]


def read_experiments(root: str | Path, groups: str | Sequence[str] | None = None,
                     key: str = "data.root") -> list[SkabExperiment]:
    """The experiments of a SKAB folder, in a stable order.

    Parameters
    ----------
    root : str or Path
        SKAB's ``data/`` folder (module docstring).
    groups : str or sequence of str, optional
        Folders to read among ``valve1``, ``valve2``, ``other``, ``anomaly-free``; None: the three
        folders with anomalies (34 experiments). Read in :data:`GROUPS` order whatever the order given.
    key : str
        The configuration key or option ``root`` came from, named in the errors.

    Returns
    -------
    list of SkabExperiment
        valve1, valve2, other (then anomaly-free), each folder by its files' integer number.
    """
    folder = check_root(root, key)
    chosen = check_groups(groups)
    out: list[SkabExperiment] = []
    for group in chosen:
        if group == FREE:
            out.append(read_anomaly_free(folder, key))
            continue
        for number, path in _numbered_files(folder / group, key):
            out.append(_experiment(path, group, f"{group}/{number}", key))
    return out


def read_anomaly_free(root: str | Path, key: str = "data.root") -> SkabExperiment:
    """``anomaly-free/anomaly-free.csv``: labels all False, every row the fit part."""
    folder = check_root(root, key)
    path = folder / FREE / f"{FREE}.csv"
    if not path.is_file():
        raise ConfigError(f"{key}={str(root)!r}: {path} is missing; allowed: SKAB's data folder with "
                          f"{FREE}/{FREE}.csv")
    return _experiment(path, FREE, f"{FREE}/{FREE}", key)


def check_root(root, key: str = "data.root") -> Path:
    """``root`` as a folder of SKAB's layout (one line naming ``key`` otherwise)."""
    if root is None or str(root) in ("", "???"):
        raise ConfigError(f"{key} is not set; allowed: SKAB's data folder (a clone of github.com/waico/SKAB, "
                          f"its data/), e.g. {key}=SKAB/data")
    folder = Path(str(root)).expanduser()
    if not folder.is_dir():
        raise ConfigError(f"{key}={str(root)!r} is not a directory; allowed: SKAB's data folder with "
                          f"{', '.join(GROUPS)}")
    if not any((folder / g).is_dir() for g in GROUPS):
        raise ConfigError(f"{key}={str(root)!r} has none of SKAB's folders; allowed: a folder with "
                          f"{', '.join(GROUPS)} (SKAB's data/)")
    return folder


def check_groups(groups, key: str = "groups") -> tuple[str, ...]:
    """Folder names among :data:`GROUPS`, in :data:`GROUPS` order; None: the anomaly folders."""
    if groups is None:
        return ANOMALY_GROUPS
    names = [groups] if isinstance(groups, str) else [str(g) for g in groups]
    for name in names:
        if name not in GROUPS:
            raise ConfigError(f"{key}: {name!r} is not a SKAB folder; allowed: {', '.join(GROUPS)}")
    if not names or len(set(names)) != len(names):
        raise ConfigError(f"{key}={names} is not a set of folders; allowed: distinct names among "
                          f"{', '.join(GROUPS)}")
    return tuple(g for g in GROUPS if g in names)


def _numbered_files(folder: Path, key: str) -> list[tuple[int, Path]]:
    if not folder.is_dir():
        raise ConfigError(f"{key}: folder {folder} is missing; allowed: SKAB's data folder with "
                          f"{', '.join(ANOMALY_GROUPS)}/N.csv")
    files = []
    for path in folder.glob("*.csv"):
        if path.stem.isdigit():
            files.append((int(path.stem), path))
    if not files:
        raise ConfigError(f"{key}: {folder} has no numbered CSV file; allowed: files 0.csv, 1.csv, ...")
    return sorted(files)


def _experiment(path: Path, group: str, name: str, key: str) -> SkabExperiment:
    labelled = group != FREE
    time, values, labels = _read(str(path), path.stat().st_mtime, labelled, key)
    n = len(values)
    if labelled and n <= FIT_ROWS:
        raise ConfigError(f"{key}: {path} has {n} rows; allowed: more than {FIT_ROWS} (SKAB's fit part, then "
                          "the test part)")
    anomaly = labels[:, 0] if labelled else np.zeros(n, bool)
    changepoint = labels[:, 1] if labelled else np.zeros(n, bool)
    return SkabExperiment(group=group, name=name, time=time, values=values, tags=TAGS, anomaly=anomaly,
                          changepoint=changepoint, fit_rows=FIT_ROWS if labelled else n)


@functools.lru_cache(maxsize=64)
def _read(path: str, mtime: float, labelled: bool, key: str):
    """One file's time, values and labels, read-only (cached while the file is unchanged)."""
    try:
        import pandas as pd
    except ImportError:
        raise ConfigError('data=skab needs pandas, a dependency of mosd: pip install "pandas>=2.0"') from None
    try:
        frame = pd.read_csv(path, sep=SEP)
    except Exception as exc:
        raise ConfigError(f"{key}: {path} cannot be read: {type(exc).__name__}: {' '.join(str(exc).split())}; "
                          f"allowed: SKAB's ';'-separated CSV") from None
    needed = (TIME, *TAGS, *(LABELS if labelled else ()))
    missing = [c for c in needed if c not in frame.columns]
    if missing:
        raise ConfigError(f"{key}: {path} has no column {missing[0]!r}; allowed: SKAB's columns "
                          f"{', '.join(needed)} (';'-separated)")
    if frame.empty:
        raise ConfigError(f"{key}: {path} has no data row; allowed: SKAB's recordings")
    stamps = pd.to_datetime(frame[TIME], errors="coerce", format="%Y-%m-%d %H:%M:%S")
    if stamps.isna().any():
        row = int(np.flatnonzero(stamps.isna().to_numpy())[0])
        raise ConfigError(f"{key}: {path} column {TIME!r} row {row} holds {str(frame[TIME].iloc[row])!r}, not a "
                          "time; allowed: YYYY-MM-DD HH:MM:SS")
    time = stamps.to_numpy().astype("datetime64[s]")
    back = np.flatnonzero(np.diff(time) <= np.timedelta64(0, "s"))
    if back.size:
        row = int(back[0]) + 1
        raise ConfigError(f"{key}: {path} row {row}: time {time[row]} does not follow {time[row - 1]}; "
                          "allowed: strictly increasing times")
    values = _numbers(frame, TAGS, path, key, "finite numbers")
    labels = np.zeros((len(frame), 0), bool)
    if labelled:
        raw = _numbers(frame, LABELS, path, key, "0 or 1")
        bad = ~np.isin(raw, (0.0, 1.0))
        if bad.any():
            row, col = (int(i) for i in np.argwhere(bad)[0])
            raise ConfigError(f"{key}: {path} column {LABELS[col]!r} row {row} holds {raw[row, col]!r}; "
                              "allowed: 0 or 1")
        labels = raw > 0.5
    for array in (time, values, labels):
        array.setflags(write=False)
    return time, values, labels


def _numbers(frame, columns: Sequence[str], path: str, key: str, allowed: str) -> np.ndarray:
    import pandas as pd

    out = np.empty((len(frame), len(columns)))
    for j, column in enumerate(columns):
        numbers = pd.to_numeric(frame[column], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
        bad = ~np.isfinite(numbers)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise ConfigError(f"{key}: {path} column {column!r} row {row} holds {str(frame[column].iloc[row])!r}; "
                              f"allowed: {allowed}")
        out[:, j] = numbers
    return out


# -- the Hydra data source (data=skab) ---------------------------------------------------------

#: rows of one scored run (a window of an experiment's test part; the scored splits need one length)
RUN_ROWS = 100
#: the monitored variables' names: the tag's, in units of its experiment's fit part (not the raw tag's)
SUFFIX = "_z"


def split_experiments(experiments: Sequence[SkabExperiment], test_share: float,
                      rng: np.random.Generator) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Training and test experiments: ``test_share`` of each folder held out, drawn with ``rng``.

    Stratified by folder so that every fault type is in both sides: a folder of ``n >= 2``
    experiments gives ``round(test_share * n)`` of them (at least 1, at most ``n - 1``) to the
    test side; a folder of one experiment gives it to training. Names in the input's order.
    """
    test: set[str] = set()
    for group in dict.fromkeys(e.group for e in experiments):
        names = [e.name for e in experiments if e.group == group]
        if len(names) < 2:
            continue
        k = min(len(names) - 1, max(1, int(round(test_share * len(names)))))
        test.update(names[i] for i in rng.permutation(len(names))[:k])
    train = tuple(e.name for e in experiments if e.name not in test)
    return train, tuple(e.name for e in experiments if e.name in test)


def standardise(experiment: SkabExperiment) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The experiment's values in units of its own fit part: ``(values - mean) / std``, mean and std.

    Mean and std (ddof 1) come from the fit part's rows not labelled anomalous only (SKAB's
    operating point moves between experiments: Volume Flow RateRMS is about 32 in valve1, 76 and
    126 in other). A tag constant over them is a one-line error naming the experiment.
    """
    fit = experiment.fit()[~experiment.anomaly[: experiment.fit_rows]]
    if len(fit) <= len(experiment.tags):
        raise ConfigError(f"data.root: {experiment.name} has {len(fit)} fit rows not labelled anomalous among its "
                          f"first {experiment.fit_rows}; allowed: more than {len(experiment.tags)} (one per tag)")
    mean, std = fit.mean(axis=0), fit.std(axis=0, ddof=1)
    flat = ~(std > 1e-12 * np.maximum(1.0, np.abs(mean)))
    if flat.any():
        raise ConfigError(f"data.root: {experiment.name}: tag {experiment.tags[int(np.flatnonzero(flat)[0])]!r} is "
                          f"constant over the fit rows; allowed: tags that vary over the first {experiment.fit_rows}")
    return (experiment.values - mean) / std, mean, std


class Skab(RecordedData):
    """SKAB's experiments as calibration, training and test splits (``data=skab``; docs/systems/skab.md).

    * every experiment is standardised by its own fit part (:func:`standardise`): the monitored
      variables are ``Accelerometer1RMS_z`` ...; one detector is then fitted on the pooled,
      standardised fit parts (the pipeline fits one model: conf/experiment/skab.yaml);
    * ``calibration``: the first :data:`FIT_ROWS` rows of every experiment, training and test
      alike (SKAB's fit parts; rows labelled anomalous there are left out, as in data=table);
    * ``training``: the test parts of the training experiments, cut into runs of ``run_rows``;
    * ``test``: the test parts of the held-out experiments, cut alike.

    The rows after the last whole run of a test part are in no split (the scored splits need one
    run length); :meth:`describe` lists every run. ``dt`` is 1 s, SKAB's median step: the rows are
    taken as they come, the few longer steps (up to 247 s, in ``other/2``) are not filled in, so a
    delay in seconds is a delay in rows.

    Parameters
    ----------
    root : str
        SKAB's data folder (required).
    groups : sequence of str, optional
        Folders among valve1, valve2, other; None: the three.
    test_share : float
        Share of each folder's experiments held out for the test split, in (0, 1).
    split_seed : int
        Seeds the generator of the hold-out draw (:func:`split_experiments`).
    test_experiments : sequence of str, optional
        The held-out experiments by name (``valve1/3``); replaces the draw.
    run_rows : int
        Rows of each scored run, 2 .. the shortest test part.
    """

    dt = 1.0
    fault_names = ("anomaly",)

    def __init__(self, root: str | None = None, groups: Sequence[str] | None = None, test_share: float = 0.5,
                 split_seed: int = 0, test_experiments: Sequence[str] | None = None, run_rows: int = RUN_ROWS):
        from ..validation import check_int

        chosen = check_groups(groups, "data.groups")
        if FREE in chosen:
            raise ConfigError(f"data.groups: {FREE!r} has no labels to score; allowed: {', '.join(ANOMALY_GROUPS)}")
        self.root = str(root) if root is not None else None
        self.groups = list(chosen)
        experiments = read_experiments(root, chosen, key="data.root")
        self.run_rows = check_int("data.run_rows", run_rows, 2)
        self.split_seed = check_int("data.split_seed", split_seed, 0, 2**63 - 1)
        try:
            share = float(test_share)
        except (TypeError, ValueError):
            share = float("nan")
        if not 0.0 < share < 1.0:
            raise ConfigError(f"data.test_share={test_share!r} is not allowed; allowed: a number in (0, 1)")
        self.test_share = share
        names = [e.name for e in experiments]
        if test_experiments is None:
            train, test = split_experiments(experiments, share, np.random.default_rng(self.split_seed))
        else:
            held = [str(n) for n in ([test_experiments] if isinstance(test_experiments, str) else test_experiments)]
            for name in held:
                if name not in names:
                    raise ConfigError(f"data.test_experiments: {name!r} is not an experiment of data.groups; "
                                      f"allowed: names such as {', '.join(names[:3])}, ...")
            if not held or len(held) == len(names) or len(set(held)) != len(held):
                raise ConfigError(f"data.test_experiments={held} is not allowed; allowed: distinct experiments, at "
                                  "least one, not all (the rest tune the detector)")
            train = tuple(n for n in names if n not in held)
            test = tuple(n for n in names if n in held)
        self.test_experiments = list(test)
        self.train_experiments, self.held_out = train, test
        self.experiments = {e.name: e for e in experiments}
        shortest = min(experiments, key=lambda e: e.n_rows - e.fit_rows)
        longest = shortest.n_rows - shortest.fit_rows
        if self.run_rows > longest:
            raise ConfigError(f"data.run_rows={self.run_rows} is longer than the test part of {shortest.name} "
                              f"({longest} rows); allowed: 2..{longest}")
        self._values = {e.name: standardise(e)[0] for e in experiments}
        self.output_names = tuple(f"{t}{SUFFIX}" for t in TAGS)
        self.check_disjoint()

    def __repr__(self) -> str:
        return (f"Skab({self.root}, {len(self.train_experiments)} training and {len(self.held_out)} test "
                f"experiments, runs of {self.run_rows} rows)")

    def values(self, source: str) -> np.ndarray:
        return self._values[source]

    def _runs(self, names: Sequence[str]) -> list[Segment]:
        out = []
        for name in names:
            e = self.experiments[name]
            for start in range(e.fit_rows, e.n_rows - self.run_rows + 1, self.run_rows):
                stop = start + self.run_rows
                out.append(Segment(name, start, stop, labels=e.anomaly[start:stop].astype(int)))
        return out

    def segments(self, split: str) -> list[Segment]:
        if split == "calibration":
            return [Segment(n, 0, e.fit_rows, labels=e.anomaly[: e.fit_rows].astype(int))
                    for n, e in self.experiments.items()]
        if split == "training":
            return self._runs(self.train_experiments)
        if split == "test":
            return self._runs(self.held_out)
        return []

    def trace(self, split: str) -> Trace:
        """As :meth:`RecordedData.trace`; the calibration's labelled rows are left out (set missing)."""
        trace = super().trace(split)
        return without_labelled_rows(trace) if split == "calibration" else trace


def write_example(root: str | Path, rng: np.random.Generator, sizes: dict[str, int] | None = None,
                  test_rows: int = 300) -> Path:
    """Write a small folder of SKAB's layout (not SKAB's numbers) for tests and bug reports.

    Two latent factors drive the 8 tags around an operating point drawn per experiment (as SKAB's
    moves between experiments); in each experiment with anomalies, Current and Pressure shift by
    4 of their standard deviations from row ``fit_rows + 20`` (sooner in a short test part) for 180
    rows (``anomaly`` 1 there, ``changepoint`` 1 at both ends). ``anomaly-free/anomaly-free.csv`` has no label columns.

    Parameters
    ----------
    root : str or Path
        The folder to write (created).
    rng : numpy.random.Generator
        Every number of the files is drawn from it.
    sizes : dict, optional
        Experiments per folder; default ``{valve1: 3, valve2: 2, other: 2}``.
    test_rows : int
        Rows after the fit part (each experiment gets 0-9 more, so that the lengths differ), at least 2.
    """
    import pandas as pd

    if int(test_rows) < 2:
        raise ConfigError(f"test_rows={test_rows!r} is not allowed; allowed: integers >= 2")

    root = Path(root)
    sizes = sizes or {"valve1": 3, "valve2": 2, "other": 2}
    loadings = rng.normal(size=(2, len(TAGS)))
    start = np.datetime64("2020-03-09T10:00:00")

    def table(n: int, hour: int) -> pd.DataFrame:
        level = rng.normal(size=len(TAGS)) * 5.0 + 50.0
        scale = rng.uniform(0.5, 2.0, size=len(TAGS))
        values = level + scale * (rng.normal(size=(n, 2)) @ loadings + 0.3 * rng.normal(size=(n, len(TAGS))))
        frame = pd.DataFrame(values, columns=list(TAGS))
        stamps = start + np.timedelta64(hour, "h") + np.arange(n).astype("timedelta64[s]")
        frame.insert(0, TIME, pd.to_datetime(stamps).strftime("%Y-%m-%d %H:%M:%S"))
        return frame

    hour = 0
    for group, count in sizes.items():
        folder = root / group
        folder.mkdir(parents=True, exist_ok=True)
        first = 0 if group != "other" else 1  # SKAB numbers other/ from 1
        for number in range(first, first + count):
            n = FIT_ROWS + test_rows + int(rng.integers(0, 10))
            frame = table(n, hour)
            hour += 1
            onset = FIT_ROWS + min(20, (n - FIT_ROWS) // 2)
            stop = min(n, onset + 180)
            anomaly = np.zeros(n)
            anomaly[onset:stop] = 1.0
            changepoint = np.zeros(n)
            changepoint[[onset, stop - 1]] = 1.0
            for tag in ("Current", "Pressure"):
                spread = frame[tag].iloc[:FIT_ROWS].std()
                frame.loc[onset:stop - 1, tag] += 4.0 * spread
            frame["anomaly"], frame["changepoint"] = anomaly, changepoint
            frame.to_csv(folder / f"{number}.csv", sep=SEP, index=False)
    (root / FREE).mkdir(parents=True, exist_ok=True)
    table(2 * FIT_ROWS, hour).to_csv(root / FREE / f"{FREE}.csv", sep=SEP, index=False)
    return root

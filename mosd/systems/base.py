"""The contract of a system's study, the one figure helper and the recorded designs (plain Python).

A *study* is what a system reports beyond the tuned design's test metrics: the
paper's Monte Carlo comparison (its tables and figures), run on the experiment
that was tuned. Every system has one subclass of :class:`Study`; the app calls
:meth:`Study.run` after the experiment when the config's ``study`` key names it
(the ``+experiment=paperNNN`` presets do), and the system's report command
(``python -m mosd.systems.paperNNN``) calls :meth:`Study.compute`,
:meth:`Study.metrics` and :meth:`Study.write_figures` on a recorded design
without running the optimiser.
"""
from __future__ import annotations

import abc
import json
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

from ..validation import ConfigError

#: the name of the optimiser's design among a study's designs; its metrics carry no prefix
TUNED = "tuned"


def check_flag(name: str, value: Any) -> bool:
    """A boolean option (YAML true/false), or a one-line :class:`ConfigError` naming it."""
    if not isinstance(value, bool):
        raise ConfigError(f"{name}={value!r} is not allowed; allowed: true, false")
    return value


def figure(width: float, height: float):
    """A matplotlib figure without pyplot: no global state, no display, safe in worker threads.

    Every study and report draws on one of these and saves it with ``fig.savefig``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def decorate(ax, xlabel: str | None = None, ylabel: str | None = None, title: str | None = None,
             title_size: float = 10, legend_size: float | None = 8, legend_loc: str | None = None) -> None:
    """The finish every study panel shares: axis labels, a title, a light grid and a legend (``None``: none)."""
    if xlabel is not None:
        ax.set_xlabel(xlabel)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    if title is not None:
        ax.set_title(title, fontsize=title_size)
    ax.grid(alpha=0.3)
    if legend_size is not None:
        ax.legend(fontsize=legend_size, **({"loc": legend_loc} if legend_loc else {}))


def design_params(detector) -> dict[str, float]:
    """A detector design's tunable parameters as plain floats (what a study records beside its numbers)."""
    return {k: float(getattr(detector, k)) for k in detector.tunable}


@lru_cache(maxsize=None)
def _designs_text(system: str) -> str:
    try:
        return resources.files(__package__).joinpath("designs", f"{system}.json").read_text()
    except FileNotFoundError:
        raise ConfigError(f"system={system!r} has no recorded designs (mosd/systems/designs/{system}.json); "
                          f"allowed: a system with a designs file") from None


#: what a report says, in one line, for a system whose preset has never been run to a recorded design
NO_RECORDED_DESIGN = ("no recorded design yet for {system}: run python -m mosd +experiment={system}, then record its "
                      "chosen design as \"tuned\" in mosd/systems/designs/{system}.json")


def has_recorded_design(system: str) -> bool:
    """True when ``mosd/systems/designs/<system>.json`` exists and holds a ``"tuned"`` design."""
    try:
        return TUNED in recorded_designs(system)
    except ConfigError:
        return False


def recorded_designs(system: str) -> dict[str, dict]:
    """The designs recorded for ``system`` (``mosd/systems/designs/<system>.json``), by name.

    ``"tuned"`` is the design the optimiser chose in the last full run of the system's preset
    (the file's ``"provenance"`` says which run), ``"paper"`` the paper's own design where it
    gives one; a report command scores them without re-running the optimiser. Keys starting
    with ``_`` are comments. Returns a fresh copy: callers may change it.
    """
    data = json.loads(_designs_text(system))
    return {k: v for k, v in data.items() if not k.startswith("_")}


def prefixed(design: str) -> str:
    """The metric prefix of a design: none for :data:`TUNED`, ``"<design>_"`` otherwise."""
    return "" if design == TUNED else f"{design}_"


class Study(abc.ABC):
    """One system's study: compute on an experiment, name the numbers, draw the figures.

    The contract every system's study keeps (:mod:`mosd.systems.paper000` … ``paper003``,
    and any new system):

    ``compute(experiment, designs) -> data``
        Simulate from the experiment's seed streams (the ``test`` stream, or ``estimator``
        for training: never what the optimiser saw), estimate with the experiment's
        estimator and decide with every detector of ``designs`` (``{name: detector}``;
        ``"tuned"`` is the optimiser's choice, other names are reference designs such as
        the paper's). Returns plain data (dicts, arrays, floats) with ``data["params"]``, the
        designs' parameters by name (:func:`design_params`); it writes nothing.
    ``metrics(data) -> {name: float}``
        The study's numbers by name. A metric that the registry
        (:mod:`mosd.metrics.registry`) defines keeps the registry's name and meaning
        (``far``, ``mdr``, ``detection_rate``, ``isolation_rate``, ...); a design other than
        ``"tuned"`` prefixes its metrics with ``"<design>_"`` (:func:`prefixed`). The class
        docstring of a subclass defines every name it returns.
    ``write_figures(data, out_dir) -> [Path]``
        PNG (or CSV) files of the data in ``out_dir``, drawn with :func:`figure` (panels
        finished with :func:`decorate`), named ``<system>_*.png``.
    ``figure_jobs(data, out_dir) -> [(method, kwargs)]``
        Optional: the same files as jobs, one per figure, that the app's figure process draws side
        by side (default: ``write_figures`` as one job). The study and its data cross to that
        process by pickle.
    ``measure(experiment, result) -> (metrics, data)``, ``run(experiment, result, out_dir) -> (metrics, files)``
        The tuned detector (``result.detector``) beside :meth:`reference_designs`, then ``metrics``;
        ``run`` also draws, with ``figures``, ``write_figures``. The app calls ``measure`` after the
        experiment (:mod:`mosd.app.run`) and hands ``figure_jobs`` to its figure process; the metrics
        land in ``summary.json`` and MLflow, the files in the run directory. Subclasses rarely
        override them.

    Subclasses set :attr:`system` (the name of the designs file and the figures' prefix),
    validate their parameters in ``__init__`` with one-line :class:`ConfigError` s that name
    the ``study.<key>`` and call ``super().__init__(figures=figures)``.

    Parameters
    ----------
    figures : bool
        Whether :meth:`run` (and the app) writes the figures.
    """

    #: the system's name: ``mosd/systems/designs/<system>.json`` and the figures' file prefix
    system: str = ""

    def __init__(self, figures: bool = True):
        self.figures = check_flag("study.figures", figures)

    @abc.abstractmethod
    def compute(self, experiment, designs: Mapping[str, Any]) -> dict:
        """The study's data for each named detector design (class docstring)."""

    @abc.abstractmethod
    def metrics(self, data: dict) -> dict[str, float]:
        """The study's numbers by name (class docstring)."""

    def write_figures(self, data: dict, out_dir: Path) -> list[Path]:
        """The study's figures in ``out_dir`` (none by default)."""
        return []

    def figure_jobs(self, data: dict, out_dir: Path) -> list[tuple[str, dict]]:
        """:meth:`write_figures` as jobs (method name, keyword arguments) that the app's figure process may draw
        at once on several processes (``mosd.app.plots.study_figures``); each method returns a path or a list of
        paths. By default one job, :meth:`write_figures` itself; a study whose figures are separate methods lists
        them, so that a machine with more cores draws them side by side."""
        return [("write_figures", {"data": data, "out_dir": Path(out_dir)})]

    def draw_figure_jobs(self, data: dict, out_dir: Path) -> list[Path]:
        """:meth:`figure_jobs` drawn here, in order: ``write_figures`` of a study that lists its figures as jobs."""
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        return [getattr(self, method)(**kwargs) for method, kwargs in self.figure_jobs(data, out_dir)]

    def reference_designs(self, experiment, detector) -> dict[str, Any]:
        """Designs scored beside the tuned ``detector`` by :meth:`run`: the paper's recorded design, if any.

        ``experiment`` is there for a system whose reference designs depend on the set-up (paper
        000's Table 3 charts differ per fault).
        """
        # a new system runs before anything is recorded: no designs file, no reference designs
        paper = recorded_designs(self.system).get("paper") if has_recorded_design(self.system) else None
        return {"paper": detector.with_params(**paper)} if paper else {}

    def run(self, experiment, result, out_dir) -> tuple[dict[str, float], list[Path]]:
        """The study of ``result.detector`` beside :meth:`reference_designs`: its metrics and its figures' files."""
        metrics, data = self.measure(experiment, result)
        files = self.write_figures(data, Path(out_dir)) if self.figures else []
        return metrics, files

    def measure(self, experiment, result) -> tuple[dict[str, float], dict]:
        """:meth:`run` without the figures: the metrics and the data :meth:`write_figures` draws.

        The app's hook: it hands the figures to its figure process (:meth:`figure_jobs`,
        ``mosd.app.plots.study_figures``), which draws them beside the run's own while this process writes the
        run's files.
        """
        designs = {TUNED: result.detector, **self.reference_designs(experiment, result.detector)}
        data = self.compute(experiment, designs)
        return self.metrics(data), data

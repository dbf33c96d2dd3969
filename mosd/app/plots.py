"""PNG figures of one run: Pareto front, chart trace, residual, optimisation history.

Figures are drawn with matplotlib's object API on the Agg canvas (no pyplot, no
display, no global figure state); matplotlib is imported on first use. Each PNG
is written under a temporary name and renamed: a run stopped mid-figure leaves
no half-written file.

:class:`FigureWriter` draws them in a side process: it starts with the run (before
the command line is checked when the machine has a core to spare:
:func:`start_early`), imports matplotlib and loads its fonts on the second core while
the run computes (0.3–0.7 s that were on the critical path), and draws the figures
while the app writes the run's other files, on one process per usable CPU (forks of
itself, warm: :func:`draw_in_parallel`).

The figures have no layout engine: :func:`_arrange` sets each figure's margins and
panel spacing once, before the draw, from what is known then (the tick labels the
axes' locators and formatters will print, the titles' lines, the axis labels, a
legend below the axes), and places the titles and axis labels itself (the draw then
skips matplotlib's search for them, which measures an axis' ticks once more).
Matplotlib's constrained layout measured every tick and text twice more than the draw
(it runs on a draw without rendering and again on the real one): it was half of each
figure's CPU. The four figures of the default command, warm, CPU seconds, best of 3
on the project's 2-core machine at load 2–2.6: 1.6–2.1 with it, 0.8–1.0 now.
"""
from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .atomic import write_atomically

#: The figures a :class:`FigureWriter` may draw (name → function of this module).
FIGURES = ("pareto_front", "pareto_pairs", "chart_trace", "residual_trace", "optimisation_history", "study_figures")


#: Resolution of the PNGs (dots per inch). The figures are made at it too: the margins are measured with
#: the renderer that draws them (and its cache of text sizes).
DPI = 110

#: Space (points) between a figure's outermost text and the canvas edge, and between neighbouring panels.
EDGE_PT, GAP_PT = 4.0, 10.0


def _figure(width: float = 6.4, height: float = 4.0):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    # no layout engine: :func:`_arrange` sets the margins once, from what is known before drawing
    # (constrained layout measured every tick label twice more than the draw: half of each figure's CPU)
    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: str | Path) -> Path:
    # a temporary file and an atomic rename: the PNG is either complete or absent (a full disk)
    return write_atomically(path, lambda out: fig.savefig(out, dpi=DPI, format="png"), binary=True)


def _tick_labels(axis, probe, renderer) -> tuple[np.ndarray, str]:
    """The tick labels ``axis`` will draw, as rows (place along the axis from 0 to 1, width, height in pixels).

    The labels are the axis' own locators and formatters applied to its view limits, as
    the draw applies them (major and minor: a log axis spanning less than a decade labels
    its minor ticks), measured as one-line texts of the tick label size; no tick is made.
    Also returns the formatter's offset text (``1e−5``, ``+1``), drawn beside the labels.
    """
    import matplotlib as mpl

    forward = axis.get_transform().transform
    lo, hi = forward(np.sort(axis.get_view_interval()))
    tol = 1e-9 * abs(hi - lo)
    probe.set_fontsize(mpl.rcParams[f"{axis.axis_name}tick.labelsize"])
    rows, offset = [], ""
    for locator, formatter in ((axis.get_major_locator(), axis.get_major_formatter()),
                               (axis.get_minor_locator(), axis.get_minor_formatter())):
        locs = np.asarray(locator(), float)
        with np.errstate(all="ignore"):
            where = forward(locs) if locs.size else locs
        inside = (where >= min(lo, hi) - tol) & (where <= max(lo, hi) + tol)
        for place, label in zip(where[inside], formatter.format_ticks(locs[inside])):
            if label:
                probe.set_text(label)
                box = probe.get_window_extent(renderer)
                rows.append(((place - lo) / (hi - lo) if hi != lo else 0.5, box.width, box.height))
        if not offset and hasattr(formatter, "get_offset"):
            offset = formatter.get_offset()
    return np.array(rows, float).reshape(-1, 3), offset


def _fit(text, room: float, renderer) -> None:
    """Re-wrap ``text`` (a Text artist) onto shorter lines until it is at most ``room`` pixels wide."""
    import textwrap

    words = " ".join(text.get_text().split())
    width = text.get_window_extent(renderer).width
    chars = max(len(line) for line in text.get_text().split("\n"))
    while width > room and chars > 10:
        chars = int(chars * min(0.95, room / width))
        text.set_text("\n".join(textwrap.wrap(words, width=chars, break_on_hyphens=False)))
        width = text.get_window_extent(renderer).width


def _arrange(fig, axes, suptitle=None, legend=None, insets=()) -> None:
    """Margins and spacing of a row of panels from what is known before drawing; no layout engine.

    Each panel needs, in pixels: on the left its widest y tick label, the tick and the
    y label; below, its x tick labels and x label (or offset text); above, its title (on
    as many lines as it has), raised above a y offset text. The outer x tick labels and
    titles wider than their panel overhang it on either side. The figure's ``suptitle`` and
    a ``legend`` at the bottom of the figure take their own height. Titles or suptitles
    wider than the canvas are re-wrapped. Panels are equally wide;
    ``fig.subplots_adjust`` places them. ``insets``: axes inside a panel, whose titles
    are only kept clear of their own offset text.
    """
    import matplotlib as mpl
    from matplotlib.text import Text

    renderer = fig.canvas.get_renderer()
    points = fig.dpi / 72.0
    width, height = fig.bbox.width, fig.bbox.height
    edge, gap = EDGE_PT * points, GAP_PT * points
    probe = Text(0, 0, "")
    probe.set_figure(fig)
    panels, raised = [], []
    for ax in axes:
        y_labels, y_offset = _tick_labels(ax.yaxis, probe, renderer)
        x_labels, x_offset = _tick_labels(ax.xaxis, probe, renderer)
        y_tick = (mpl.rcParams["ytick.major.size"] + mpl.rcParams["ytick.major.pad"]) * points
        x_tick = (mpl.rcParams["xtick.major.size"] + mpl.rcParams["xtick.major.pad"]) * points
        # how far the tick labels reach out from the axes, and half the tallest y tick label (centred on its tick)
        y_reach = y_labels[:, 1].max(initial=0.0) + y_tick
        x_reach = x_labels[:, 2].max(initial=0.0) + x_tick
        half_label = 0.5 * y_labels[:, 2].max(initial=0.0)
        left = y_reach
        if ax.yaxis.label.get_text():
            left += ax.yaxis.labelpad * points + ax.yaxis.label.get_window_extent(renderer).width
        x_label = (ax.xaxis.label.get_window_extent(renderer).height + ax.xaxis.labelpad * points
                   if ax.xaxis.label.get_text() else 0.0)
        below = x_reach + max(x_label, _offset_height(ax.xaxis, x_offset, probe, renderer))
        lift = _offset_height(ax.yaxis, y_offset, probe, renderer)
        raised.append((ax, lift))
        above = half_label  # the top tick label is centred on the top edge
        title = 0.0
        if ax.title.get_text():
            if ax.title.get_window_extent(renderer).width > width - 2 * edge:
                _fit(ax.title, width - 2 * edge, renderer)
            box = ax.title.get_window_extent(renderer)
            above, title = max(above, lift + mpl.rcParams["axes.titlepad"] * points + box.height), box.width
        panels.append(dict(left=left, below=max(below, half_label), above=above, title=title, x_labels=x_labels,
                           y_reach=y_reach, x_reach=x_reach))
    for inset in insets:
        raised.append((inset, _offset_height(inset.yaxis, _tick_labels(inset.yaxis, probe, renderer)[1], probe,
                                             renderer)))
    top = max(p["above"] for p in panels) + edge
    if suptitle is not None and suptitle.get_text():
        if suptitle.get_window_extent(renderer).width > width - 2 * edge:
            _fit(suptitle, width - 2 * edge, renderer)
        # the suptitle hangs by its top from its y (a fraction of the figure's height)
        top += (1.0 - suptitle.get_position()[1]) * height + suptitle.get_window_extent(renderer).height
    bottom = max(p["below"] for p in panels) + edge
    if legend is not None:  # at the figure's bottom edge: the panels stand on it
        bottom += legend.get_window_extent(renderer).y1

    def overhang(panel: dict, wide: float) -> tuple[float, float]:
        """Pixels a panel ``wide`` pixels wide has text beyond its left and right edges (title, x tick labels)."""
        place, label = panel["x_labels"][:, 0], panel["x_labels"][:, 1]
        title = max(0.0, 0.5 * (panel["title"] - wide))
        return (max(title, *(0.5 * label - place * wide), 0.0),
                max(title, *(0.5 * label - (1.0 - place) * wide), 0.0))

    # the overhangs depend on the panels' width, which depends on the margins: a few rounds settle them
    n = len(panels)
    left = right = between = 0.0
    for _ in range(4):
        wide = (width - left - right - (n - 1) * between) / n
        sides = [overhang(p, wide) for p in panels]
        left = max(panels[0]["left"], sides[0][0]) + edge
        right = sides[-1][1] + edge
        between = max([0.0, *(max(b["left"], a_side[1] + b_side[0]) + gap
                              for b, a_side, b_side in zip(panels[1:], sides, sides[1:]))])
    wide = max((width - left - right - (n - 1) * between) / n, 1.0)
    fig.subplots_adjust(left=left / width, right=1.0 - right / width, bottom=bottom / height,
                        top=1.0 - top / height, wspace=between / wide if n > 1 else None)
    # titles and axis labels are given their places here, once the panels are placed: the draw then skips
    # matplotlib's search for them (each measures the ticks of the axis once more). A title is made at a
    # fixed height (``set_title(..., y=1.0)``), raised above an offset text; an axis label stands its pad
    # off the tick labels, as matplotlib places it (an inset's are empty: only the search is skipped)
    for ax, lift in raised:
        if lift and ax.title.get_text():
            ax.title.set_y(1.0 + lift / max(ax.get_window_extent(renderer).height, 1.0))
    for ax, panel in zip(axes, panels):
        box = ax.get_window_extent(renderer)
        ax.yaxis.set_label_coords(-(panel["y_reach"] + ax.yaxis.labelpad * points) / max(box.width, 1.0), 0.5)
        ax.xaxis.set_label_coords(0.5, -(panel["x_reach"] + ax.xaxis.labelpad * points) / max(box.height, 1.0))
    for inset in insets:
        inset.xaxis.set_label_coords(0.5, 0.0)
        inset.yaxis.set_label_coords(0.0, 0.5)


def _offset_height(axis, offset: str, probe, renderer) -> float:
    """Pixels the offset text ``offset`` of ``axis`` takes beside its tick labels, its pad included (0: none)."""
    if not offset:
        return 0.0
    probe.set_fontsize(axis.offsetText.get_fontsize())
    probe.set_text(offset)
    return probe.get_window_extent(renderer).height + axis.OFFSETTEXTPAD * axis.get_figure(root=True).dpi / 72.0


def onsets(fault_mask: np.ndarray) -> np.ndarray:
    """Indices where a fault starts: every rising edge of the mask (a recording's test rows hold several)."""
    mask = np.asarray(fault_mask, bool).astype(np.int8)
    return np.flatnonzero(np.diff(mask, prepend=0) > 0)


def wrapped(title: str, width: int = 90) -> str:
    """``title`` on as many lines of at most ``width`` characters as it needs (a long design would be clipped)."""
    import textwrap

    return "\n".join(textwrap.wrap(title, width=width, break_on_hyphens=False)) if len(title) > width else title


def _finish_time_axes(ax, t: np.ndarray, fault_mask: np.ndarray, ylabel: str, title: str) -> None:
    """Fault-onset markers (every one), labels, grid and legend shared by the time-series plots."""
    for i, k in enumerate(onsets(fault_mask)):
        ax.axvline(t[k], color="k", lw=1.0, ls=":", label="fault onset" if i == 0 else None)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(ylabel)
    ax.set_title(wrapped(title), y=1.0)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)


def zoom_box(F: np.ndarray) -> tuple[float, float, float, float] | None:
    """Axis limits around the archive's useful region, or None when the whole archive is that region.

    The useful region is the designs whose sum of the two objectives is at most
    twice the best sum plus 0.01 (for FAR and MDR: an accuracy within about one
    point of the best when the best is good), padded by a tenth of its size.
    Extreme designs (alarm almost always, almost never) stay in the inset.
    """
    F = np.atleast_2d(np.asarray(F, float))
    total = F.sum(axis=1)
    best = float(total.min())
    near = F[total <= max(2.0 * best, best + 0.01)]
    if len(near) == len(F):
        return None
    low, high = near.min(axis=0), near.max(axis=0)
    pad = np.maximum(0.1 * (high - low), 1e-4)
    # rates cannot be negative: show just a sliver below zero
    bottom = np.maximum(low - pad, np.minimum(low, 0.0) - 0.03 * (high + pad))
    return bottom[0], high[0] + pad[0], bottom[1], high[1] + pad[1]


def pareto_front(path: str | Path, F: np.ndarray, chosen: int | None = None, title: str = "",
                 labels: tuple[str, str] = ("far", "mdr")) -> Path:
    """The archive in the plane of two objectives, zoomed on its useful part, the chosen design highlighted.

    Parameters
    ----------
    path : output PNG
    F : ndarray (n, 2)
        The objectives on the training replications (eq. 36: FAR and MDR).
    chosen : int, optional
        Row of the chosen design.
    labels : pair of str
        The objectives' names.

    When some designs are far from the best trade-off (:func:`zoom_box`) the
    axes zoom on the designs near it and an inset shows the whole archive.
    """
    F = np.atleast_2d(np.asarray(F, float))
    fig = _figure()
    ax = fig.add_subplot()
    order = np.argsort(F[:, 0])

    def draw(axes, small=False):
        axes.plot(F[order, 0], F[order, 1], "o-", ms=2.5 if small else 4, lw=0.8, color="tab:blue",
                  label=None if small else f"archive (training), {len(F)} designs")
        if chosen is not None:
            axes.plot(F[chosen, 0], F[chosen, 1], "*", ms=8 if small else 14, color="tab:red",
                      label=None if small else f"chosen: {labels[0]} {F[chosen, 0]:.4g}, {labels[1]} {F[chosen, 1]:.4g}")

    draw(ax)
    box = zoom_box(F) if F.shape[0] > 2 else None
    insets = []
    if box is not None:
        ax.set_xlim(box[0], box[1])
        ax.set_ylim(box[2], box[3])
        inset = ax.inset_axes([0.62, 0.42, 0.35, 0.33])
        draw(inset, small=True)
        inset.set_title("whole archive", fontsize=7, y=1.0)
        inset.tick_params(labelsize=6)
        inset.grid(alpha=0.3)
        inset.indicate_inset([box[0], box[2], box[1] - box[0], box[3] - box[2]], edgecolor="0.4")
        insets.append(inset)
    names = {"far": "false-alarm rate FAR", "mdr": "missed-detection rate MDR"}
    ax.set_xlabel(names.get(labels[0], labels[0]))
    ax.set_ylabel(names.get(labels[1], labels[1]))
    ax.set_title((title or "Pareto front") + (" (zoom on the best trade-offs)" if box is not None else ""),
                 fontsize=10, y=1.0)
    ax.grid(alpha=0.3)
    # below the axes: inside, it can cover the chosen design's star (the best trade-off sits in a corner)
    legend = fig.legend(loc="lower center", ncols=2, fontsize=8)
    _arrange(fig, [ax], legend=legend, insets=insets)
    return _save(fig, path)


def chart_trace(path: str | Path, t: np.ndarray, statistic: np.ndarray, ucl: np.ndarray, fault_mask: np.ndarray,
                title: str = "") -> Path:
    """The plotted chart statistic l_k of one test replication with its UCL and the fault onset.

    Parameters
    ----------
    t : ndarray (K,)
        Time (s) of each chart point (the last sample of its subgroup).
    statistic, ucl : ndarray (K,)
        l_k and UCL_k (a constant limit is a constant array).
    fault_mask : ndarray of bool (K,)
    """
    t = np.asarray(t, float)
    statistic = np.asarray(statistic, float)
    ucl = np.broadcast_to(np.asarray(ucl, float), statistic.shape)
    fault_mask = np.asarray(fault_mask, bool)
    fig = _figure(7.5, 4.3)
    ax = fig.add_subplot()
    ax.plot(t, statistic, lw=0.9, color="tab:blue", label="chart statistic $l_k$")
    ax.plot(t, ucl, lw=1.2, color="tab:red", ls="--", label="UCL")
    alarms = statistic > ucl
    ax.plot(t[alarms], statistic[alarms], ".", ms=3, color="tab:red", label="alarm")
    scale = chart_scale(statistic, ucl)
    if scale == "log":
        ax.set_yscale("log")
    elif scale == "symlog":
        # linear up to the limit, logarithmic beyond: the in-control part keeps its detail
        ax.set_yscale("symlog", linthresh=float(np.nanmax(np.abs(ucl))))
    in_control = int(np.sum(~alarms & ~fault_mask))
    false_alarms = int(np.sum(alarms & ~fault_mask))
    note = f"; {false_alarms} false alarms in {in_control + false_alarms} fault-free points"
    _finish_time_axes(ax, t, fault_mask, "$l_k$" + (" (log scale)" if scale != "linear" else ""),
                      (title or "Chart on one test replication") + note)
    ax.title.set_fontsize(9)
    _arrange(fig, [ax])
    return _save(fig, path)


def chart_scale(statistic: np.ndarray, ucl: np.ndarray, ratio: float = 10.0) -> str:
    """``linear``, or ``log``/``symlog`` when the statistic rises ``ratio`` times above the limit.

    A post-fault excursion of 60 against a limit of 2 flattens the in-control part
    (and its false alarms) on a linear axis.
    """
    statistic = np.asarray(statistic, float)
    limit = float(np.nanmax(np.abs(ucl))) if np.size(ucl) else 0.0
    finite = statistic[np.isfinite(statistic)]
    if finite.size == 0 or limit <= 0 or np.max(np.abs(finite)) < ratio * limit:
        return "linear"
    return "log" if np.min(finite) > 0 else "symlog"


def residual_trace(path: str | Path, residual: np.ndarray, fault_mask: np.ndarray, dt: float,
                   mean: float = 0.0, sigma: float | None = None, channel_name: str = "", title: str = "") -> Path:
    """The monitored residual of one test replication with the fault onset and the Phase-I μ ± σ band."""
    residual = np.asarray(residual, float)
    fault_mask = np.asarray(fault_mask, bool)
    t = dt * np.arange(residual.size)
    fig = _figure(7.5, 4.0)
    ax = fig.add_subplot()
    ax.plot(t, residual, lw=0.5, color="tab:blue", label=f"residual {channel_name}".strip())
    if sigma is not None and np.isfinite(sigma):
        ax.axhspan(mean - sigma, mean + sigma, color="tab:green", alpha=0.15, label="Phase-I μ ± σ")
    _finish_time_axes(ax, t, fault_mask, "residual", title or "Residual on one test replication")
    _arrange(fig, [ax])
    return _save(fig, path)


def history_limits(values: Sequence[float], scale: float, cap: float | None = None) -> tuple[float, float] | None:
    """y-limits showing at least ``scale`` around the values (None: nothing finite to show).

    A hypervolume moving by 0.02 % must not fill the panel as if it jumped:
    the axis spans at least ``scale`` (e.g. 5 % of the largest value).
    """
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    low, high = float(v.min()), float(v.max())
    span = max(high - low, scale)
    middle = 0.5 * (low + high)
    bottom, top = middle - 0.55 * span, middle + 0.55 * span
    if cap is not None and top > cap and high <= cap:  # no room above the largest possible value
        bottom, top = bottom - (top - cap), cap + 0.02 * span
    return bottom, top


def optimisation_history(path: str | Path, records: Sequence[dict], title: str = "") -> Path:
    """Hypervolume, archive size and best accuracy per generation, on honest y-ranges."""
    fig = _figure(7.5, 4.0)
    axes = fig.subplots(1, 3)
    gen = [r["generation"] for r in records]
    from matplotlib.ticker import MaxNLocator

    # (key, label, smallest span shown, largest possible value)
    panels = (("hypervolume", "hypervolume (ref 1.1, 1.1)", 0.05, 1.21), ("archive_size", "archive size", 2.0, None),
              ("best_accuracy", "best 1 − FAR − MDR", 0.02, 1.0))
    for ax, (key, label, floor, cap) in zip(axes, panels):
        values = [r[key] for r in records]
        ax.plot(gen, values, "o-", ms=2.5, lw=1.2)
        finite = [v for v in values if np.isfinite(v)]
        limits = history_limits(values, max(floor, 0.05 * max(abs(v) for v in finite)) if finite else floor, cap)
        if limits is not None:
            ax.set_ylim(*limits)
        if key == "archive_size":
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_xlabel("generation")
        ax.set_title(label, fontsize=9, y=1.0)
        ax.grid(alpha=0.3)
    n_eval = records[-1].get("n_eval") if records else None
    suptitle = fig.suptitle(title or (f"Optimisation history: {len(gen)} generations"
                                      + (f", {int(n_eval)} evaluations" if n_eval else "")), fontsize=10)
    _arrange(fig, axes, suptitle=suptitle)
    return _save(fig, path)


def pareto_pairs(path: str | Path, F: np.ndarray, chosen: int | None = None, title: str = "",
                 labels: tuple[str, ...] = ()) -> Path:
    """An archive of three or more objectives: every pair of objectives in its own panel, chosen design starred."""
    F = np.atleast_2d(np.asarray(F, float))
    d = F.shape[1]
    labels = tuple(labels) or tuple(f"f{i + 1}" for i in range(d))
    pairs = [(i, j) for i in range(d) for j in range(i + 1, d)]
    fig = _figure(3.4 * len(pairs), 3.4)
    axes = np.atleast_1d(fig.subplots(1, len(pairs)))
    finite = np.isfinite(F).all(axis=1)
    for ax, (i, j) in zip(axes, pairs):
        ax.scatter(F[finite, i], F[finite, j], s=10, color="tab:blue", label="archive (training)")
        if chosen is not None and finite[chosen]:
            ax.plot(F[chosen, i], F[chosen, j], "*", ms=13, color="tab:red", label="chosen")
        ax.set_xlabel(labels[i])
        ax.set_ylabel(labels[j])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=7)
    _arrange(fig, axes, suptitle=fig.suptitle(title or f"Archive over {d} objectives"))
    return _save(fig, path)


# ------------------------------------------------------------------------------------
# drawing in a side process
# ------------------------------------------------------------------------------------
def _load_drawing() -> None:
    """Import what drawing needs: matplotlib's figure and Agg canvas (and with them its font list)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401


def _warm_up(stop=None) -> None:
    """Load what drawing needs before the figures arrive: matplotlib, its fonts, the Agg canvas, the PNG writer.

    One small figure with the figures' parts (their layout, title, labels, log-scale ticks,
    legend, grid), saved as PNG into memory. Drawing each kind of figure once (the warm-up before
    issue 32's warm-start pass) cost 1.1–1.7 s of CPU and saved 0.1–0.3 s on the run's four figures
    (measured on the project's 2-core machine, load 3); at its nice value it was still running when
    the figures arrived in every run measured, so they were drawn beside it, on one process
    (:func:`_serve` forks no drawer beside a thread at work). ``stop`` (a ``threading.Event``): real
    work has arrived, the figure is not drawn.
    """
    import io

    _load_drawing()
    if stop is not None and stop.is_set():
        return
    fig = _figure(2.0, 1.5)
    ax = fig.add_subplot()
    ax.plot([0.01, 0.02], [1.0, 40.0], label="warm-up")
    ax.set_yscale("log")
    ax.set_title("warm-up", y=1.0)
    ax.set_xlabel("time (s)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    _arrange(fig, [ax])
    fig.savefig(io.BytesIO(), dpi=DPI, format="png")


#: Nice value of the warm-up figure's thread (Linux: per thread): the run's own processes come first.
WARM_UP_NICE = 10

#: Seconds the figures wait for the warm-up figure to end (it is drawn on, beside them, past that).
WARM_UP_WAIT_S = 0.25


def _warm_up_in_background(stop) -> None:
    """:func:`_warm_up` in its own thread (see :func:`_serve`): the imports at the normal priority, the figure lower.

    The imports are not lowered: the figures need them, and drawing them waits on the import lock
    this thread holds; at nice 10 on a busy 2-core machine the imports were still running when the
    figures arrived (2 runs in 3 at load 3), and the figures waited for them at that priority.
    """
    import threading

    try:
        _load_drawing()
        if sys.platform.startswith("linux"):
            # on Linux a nice value belongs to a thread: only the warm-up yields, not the drawing
            try:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WARM_UP_NICE)
            except OSError:
                pass
        _warm_up(stop)
    except Exception:  # a warm-up is an optimisation: the real figures report real errors
        pass


def study_figures(study, method: str, kwargs: dict) -> list[Path]:
    """One of a system's study figure jobs (:meth:`mosd.systems.base.Study.figure_jobs`): ``study.method(**kwargs)``,
    its path or paths as a list.

    A job like the run's own figures, so that a study's figures, drawn in the run's process before, are drawn
    by the figure process beside the run's (1.4–4 s of a preset's study on the 2-core machine; issue 32).
    """
    drawn = getattr(study, method)(**kwargs)
    return [Path(p) for p in drawn] if isinstance(drawn, (list, tuple)) else [Path(drawn)]


def draw(jobs: Sequence[tuple[str, dict[str, Any]]]) -> list[Path]:
    """Draw ``(figure name, keyword arguments)`` jobs in this process, in order; the PNG paths."""
    return _flat(_draw_each(jobs))


def _draw_each(jobs: Sequence[tuple[str, dict[str, Any]]]) -> list[list[Path]]:
    """Each job's PNG paths, in order: one for a run figure, a study's for :func:`study_figures`."""
    out = []
    for name, kwargs in jobs:
        if name not in FIGURES:
            raise ValueError(f"{name!r} is not a figure; allowed: {', '.join(FIGURES)}")
        drawn = globals()[name](**kwargs)
        out.append(drawn if isinstance(drawn, list) else [drawn])
    return out


def _flat(per_job: Sequence[Sequence]) -> list[Path]:
    return [Path(p) for drawn in per_job for p in drawn]


#: Relative drawing cost of each figure (CPU seconds, warm, best of 3, measured on the project's 2-core machine
#: at load 2: the chart's log-scale ticks are the dearest): how :func:`shares` balances the drawing processes.
FIGURE_COST = {"chart_trace": 0.30, "optimisation_history": 0.26, "pareto_pairs": 0.25, "pareto_front": 0.22,
               "residual_trace": 0.21, "study_figures": 0.8}


def shares(jobs: Sequence[tuple[str, dict[str, Any]]], drawers: int) -> list[list[int]]:
    """The job indices of each of ``drawers`` processes, balanced by :data:`FIGURE_COST` (largest first).

    Empty shares are dropped; each share keeps the jobs' order.
    """
    loads = [[0.0, []] for _ in range(max(1, min(int(drawers), len(jobs))))]
    for i in sorted(range(len(jobs)), key=lambda i: -FIGURE_COST.get(jobs[i][0], 1.0)):
        least = min(loads, key=lambda load: load[0])
        least[0] += FIGURE_COST.get(jobs[i][0], 1.0)
        least[1].append(i)
    return [sorted(indices) for _, indices in loads if indices]


def _die_with_parent(parent: int) -> bool:
    """Linux: this (forked) process is killed when ``parent`` dies; False where that cannot be arranged."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, 9, 0, 0, 0) != 0:  # PR_SET_PDEATHSIG, SIGKILL
            return False
    except (OSError, AttributeError):
        return False
    return os.getppid() == parent  # the parent may have died before the call


def draw_in_parallel(jobs: Sequence[tuple[str, dict[str, Any]]], drawers: int) -> list[Path]:
    """:func:`draw` on ``drawers`` processes: this one and ``drawers - 1`` forks of it (Linux), same files.

    The figure process has matplotlib loaded and warm: a fork starts drawing at once
    and shares those pages. Each fork draws its share (:func:`shares`) and dies with
    this process (a figure process killed by the app leaves no drawer behind to write
    a PNG later). The first error, here or in a fork, is raised once every fork has
    ended. One drawer, or no ``fork``: :func:`draw`.
    """
    parts = shares(jobs, drawers)
    if len(parts) < 2 or not sys.platform.startswith("linux"):
        return draw(jobs)
    parent, forks = os.getpid(), []
    for part in parts[1:]:
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:  # the fork: draw its share, reply on its pipe, leave without any teardown
            code = 1
            try:
                os.close(read)
                if _die_with_parent(parent):
                    try:
                        drawn = _draw_each([jobs[i] for i in part])
                        reply = {"ok": True, "paths": [[str(p) for p in paths] for paths in drawn]}
                    except Exception as exc:
                        reply = {"ok": False, "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
                    with os.fdopen(write, "wb") as out:
                        pickle.dump(reply, out)
                    code = 0
            finally:
                os._exit(code)
        os.close(write)
        forks.append((pid, read, part))
    paths: list = [None] * len(jobs)
    error = None
    try:
        for i, path in zip(parts[0], _draw_each([jobs[i] for i in parts[0]])):
            paths[i] = path
    except Exception as exc:
        error = exc
    for pid, read, part in forks:
        with os.fdopen(read, "rb") as replies:
            try:
                reply = pickle.load(replies)
            except (EOFError, pickle.UnpicklingError):
                reply = {"ok": False, "error": "a drawing process ended without drawing its figures"}
        os.waitpid(pid, 0)
        if reply["ok"]:
            for i, path in zip(part, reply["paths"]):
                paths[i] = path
        elif error is None:
            error = RuntimeError(reply["error"])
    if error is not None:
        raise error
    return _flat(paths)


def usable_cpus() -> int:
    """The CPUs this process may run on.

    :func:`mosd.optim.workers.available_cpus`'s arithmetic, not imported from there: importing ``mosd.optim``
    loads pymoo, which neither the figure process nor the check before preflight (:func:`mosd.app.spare_core`)
    needs."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def free_cpus() -> int:
    """The usable CPUs no runnable thread holds right now (negative: threads queue for them), this one's included.

    Linux: the runnable threads of the whole machine at this instant (the fourth field of
    ``/proc/loadavg``), which sees a busy machine at once where the 1-minute load average
    lags a minute behind (and counts a run's own previous minute); elsewhere that average,
    rounded up. What extra processes can use without taking time from other work: the figures
    are drawn on more than one process (:func:`_serve`), and the side processes start before
    the checks (:func:`mosd.app.spare_core`), only when it is at least one.
    """
    import math

    try:
        with open("/proc/loadavg") as fh:
            runnable = int(fh.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        try:
            runnable = math.ceil(os.getloadavg()[0]) + 1  # + this thread, which the average has not seen yet
        except (AttributeError, OSError):
            return 0
    return usable_cpus() - runnable


def _serve(drawers: int = 0) -> None:
    """Side-process main: warm up, then draw each pickled job list from stdin; pickled replies on stdout.

    ``drawers``: processes that may draw a job list (0: one per usable CPU), see :func:`draw_in_parallel`;
    no more than one plus the CPUs free (:func:`free_cpus`): on a busy machine a fork would only add
    its copying (about 15 % more CPU for the four figures) to a queue of work.
    """
    import signal

    # the app ends this process when it stops (close or kill): a Ctrl-C meant for the app must not
    # print a traceback from here first
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import threading

    requests, replies = sys.stdin.buffer, os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything a library prints must not corrupt the reply channel
    # the warm-up runs while the run computes, at a lower priority (the run's processes are on the
    # critical path, the warm-up is not); the figures themselves are drawn by this thread at the
    # normal priority, once the warm-up has finished or stopped between two figures
    stop = threading.Event()
    warm = threading.Thread(target=_warm_up_in_background, args=(stop,), name="mosd-figures-warm-up", daemon=True)
    warm.start()
    while True:
        try:
            jobs = pickle.load(requests)
        except EOFError:  # the app closed the channel (or died): nothing more to draw
            break
        stop.set()
        # a warm-up figure starved by a busy machine is not waited for: the figures are drawn here meanwhile,
        # on this process alone (a fork of a process with a second thread at work could inherit its locks)
        warm.join(WARM_UP_WAIT_S)
        try:
            # one drawer more than the free CPUs, the app's counted as free: it waits once its text files are written
            free = free_cpus() + 1
            paths = draw_in_parallel(jobs, 1 if warm.is_alive() else min(drawers or usable_cpus(), 1 + max(0, free)))
            reply = {"ok": True, "paths": [str(p) for p in paths]}
        except Exception as exc:  # reported to the app, which draws in-process instead
            reply = {"ok": False, "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
        pickle.dump(reply, replies)
        replies.flush()
    os._exit(0)  # no teardown with matplotlib loaded: the app does not wait for it


class FigureWriter:
    """Draws figures in a side process started at construction (see the module docstring).

    ``drawers``: how many processes draw a job list at once (:func:`draw_in_parallel`);
    None, one per CPU the side process may use (a sweep's job passes its share of the cores).

    :meth:`submit` sends a job list and returns at once; :meth:`result` waits for
    the PNGs. Whatever goes wrong in the side process (it could not start, it
    died, a figure raised), :meth:`result` draws the jobs in this process
    instead, so a figure is never lost to the optimisation of its drawing.
    :meth:`close` (idempotent) ends the process.
    """

    def __init__(self, drawers: int | None = None):
        package_parent = str(Path(__file__).resolve().parents[2])  # the directory holding mosd/
        self._stderr = tempfile.TemporaryFile()
        self._jobs: list[tuple[str, dict[str, Any]]] | None = None
        #: the ``drawers`` it was started with (0: one per usable CPU): a kept writer serves a job asking the same
        self.drawers = max(0, int(drawers or 0))
        #: why the last :meth:`result` drew in this process (None: the side process drew)
        self.fallback: str | None = None
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
                 "from mosd.app.plots import _serve; _serve(int(sys.argv[2]))", package_parent,
                 str(self.drawers)],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr)
        except OSError as exc:
            self._proc, self.fallback = None, f"the figure process did not start: {exc}"

    def submit(self, jobs: Sequence[tuple[str, dict[str, Any]]]) -> None:
        """Send ``(figure name, keyword arguments)`` jobs (see :data:`FIGURES`); returns at once."""
        self._jobs = [(name, dict(kwargs)) for name, kwargs in jobs]
        if self._proc is None:
            return
        try:
            payload = pickle.dumps(self._jobs)
        except Exception as exc:  # noqa: BLE001 - a job that cannot cross (a study holding an open resource): drawn here
            fallback = f"the figures could not be sent to the figure process: {type(exc).__name__}: {exc}"
            self.close(wait=False)
            self.fallback = fallback
            return
        try:
            self._proc.stdin.write(payload)
            self._proc.stdin.flush()
        except OSError as exc:
            self.fallback = f"the figure process ended: {exc}"
            self._kill()

    def result(self) -> list[Path]:
        """The PNG paths of the submitted jobs, drawn by the side process or else here."""
        jobs, self._jobs = self._jobs or [], None
        if self._proc is not None:
            try:
                reply = pickle.load(self._proc.stdout)
            except (EOFError, OSError, pickle.UnpicklingError) as exc:
                reply = {"ok": False, "error": f"the figure process ended ({exc or 'no reply'}): "
                                               f"{self._stderr_tail()}"}
            if reply.get("ok"):
                self.fallback = None
                return [Path(p) for p in reply["paths"]]
            self.fallback = reply.get("error", "no reply")
            self._kill()
        return draw(jobs)

    def alive(self) -> bool:
        """Whether the side process is running and waiting for work (no job list of this writer is pending)."""
        return self._proc is not None and self._jobs is None and self.fallback is None and self._proc.poll() is None

    def close(self, wait: bool = True) -> None:
        """End the side process (it draws nothing more); ``wait=False`` kills it at once."""
        if self._proc is None:
            return
        if not wait:
            self._kill()
        try:
            self._proc.stdin.close()  # EOF: the process leaves its loop and exits
        except OSError:
            pass
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:  # still importing matplotlib: nothing to keep
            self._kill()
        self._proc = None
        self._stderr.close()

    def _kill(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()

    def _stderr_tail(self) -> str:
        try:
            self._stderr.seek(0)
            lines = [ln.strip() for ln in self._stderr.read().decode(errors="replace").splitlines() if ln.strip()]
        except (OSError, ValueError):
            return ""
        return lines[-1] if lines else ""


# ------------------------------------------------------------------------------------
# a single run's figure process, started before the command line is checked
# ------------------------------------------------------------------------------------
_EARLY: list[FigureWriter] = []
#: a sweep job's figure process, idle, kept for this process's next job (:func:`keep`)
_KEPT: list[FigureWriter] = []


def start_early() -> None:
    """Start the figure process now, for the run this process is about to check and start.

    Called by the app before preflight: checking the command line (composition,
    components, the dry run) keeps one core busy, and the figure process imports
    matplotlib and warms up on the other instead of beside the optimiser's threads.
    The run takes it with :func:`take`; :func:`discard` ends one nobody took.
    """
    discard()
    _EARLY.append(FigureWriter())


def take(drawers: int | None = None) -> FigureWriter:
    """The figure process :func:`start_early` started (once), else one :func:`keep` kept, else a new one.

    ``drawers`` is for a kept or a new one (a sweep's job passes its share of the cores); the early one
    draws on every usable CPU (it is only started for a single run).
    """
    if _EARLY:
        return _EARLY.pop()
    wanted = max(0, int(drawers or 0))
    while _KEPT:
        writer = _KEPT.pop()
        if writer.drawers == wanted and writer.alive():
            return writer
        writer.close(wait=False)
    return FigureWriter(drawers)


def keep(writer: FigureWriter) -> bool:
    """Keep a sweep job's figure process, its drawing done, for the next job of this process; False: closed.

    A sweep's jobs in one process (the basic launcher's, a joblib worker's) then share one
    figure process: matplotlib's import and warm-up (1.0–1.4 s of CPU on the project's 2-core
    machine) are paid once per process, not once per job. One that failed or died is closed.
    The process ends when this one does (its request pipe closes), or with :func:`discard`.
    """
    if not writer.alive():
        writer.close(wait=False)
        return False
    while _KEPT:
        _KEPT.pop().close(wait=False)
    _KEPT.append(writer)
    return True


def early_pids() -> list[int]:
    """The process id of the figure process :func:`start_early` started, while no run has taken it."""
    return [writer._proc.pid for writer in _EARLY if writer._proc is not None]


def discard() -> None:
    """End the figure process :func:`start_early` started, if no run took it (an error, a sweep), and a kept one."""
    while _EARLY:
        _EARLY.pop().close(wait=False)
    while _KEPT:
        _KEPT.pop().close(wait=False)

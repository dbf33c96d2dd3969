"""PNG figures of one run: Pareto front, chart trace, residual, optimisation history.

Figures are drawn with matplotlib's object API on the Agg canvas (no pyplot, no
display, no global figure state); matplotlib is imported on first use. Each PNG
is written under a temporary name and renamed: a run stopped mid-figure leaves
no half-written file. Where they are drawn (a side process beside the run, forks
of it) is :mod:`mosd.app.plots`'s job; :func:`_warm_up` is the small figure that
process draws to load matplotlib before the real ones arrive.

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

from pathlib import Path
from typing import Sequence

import numpy as np

from .atomic import write_atomically

#: The run's figures (name → function of this module); :mod:`mosd.app.plots` draws them by name.
FIGURES = ("pareto_front", "pareto_pairs", "chart_trace", "residual_trace", "optimisation_history")


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

    Notes
    -----
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
# the figure process's warm-up
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
    (:func:`mosd.app.plots._serve` forks no drawer beside a thread at work). ``stop`` (a ``threading.Event``): real
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

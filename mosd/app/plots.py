"""PNG figures of one run: Pareto front, chart trace, residual, optimisation history.

Figures are drawn with matplotlib's object API on the Agg canvas (no pyplot, no
display, no global figure state); matplotlib is imported on first use.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np


def _figure(width: float = 6.4, height: float = 4.0):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def _finish_time_axes(ax, t: np.ndarray, fault_mask: np.ndarray, ylabel: str, title: str) -> None:
    """Fault-onset marker, labels, grid and legend shared by the time-series plots."""
    if fault_mask.any():
        ax.axvline(t[np.argmax(fault_mask)], color="k", lw=1.0, ls=":", label="fault onset")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)


def pareto_front(path: str | Path, F: np.ndarray, chosen: int | None = None, title: str = "",
                 labels: tuple[str, str] = ("far", "mdr")) -> Path:
    """Scatter of the archive in the plane of two objectives, the chosen design highlighted.

    Parameters
    ----------
    path : output PNG
    F : ndarray (n, 2)
        The objectives on the training replications (eq. 36: FAR and MDR).
    chosen : int, optional
        Row of the chosen design.
    labels : pair of str
        The objectives' names.
    """
    F = np.atleast_2d(np.asarray(F, float))
    fig = _figure()
    ax = fig.add_subplot()
    order = np.argsort(F[:, 0])
    ax.plot(F[order, 0], F[order, 1], "o-", ms=4, lw=0.8, color="tab:blue", label="archive (training)")
    if chosen is not None:
        ax.plot(F[chosen, 0], F[chosen, 1], "*", ms=14, color="tab:red",
                label=f"chosen: {labels[0]} {F[chosen, 0]:.4g}, {labels[1]} {F[chosen, 1]:.4g}")
    names = {"far": "false-alarm rate FAR", "mdr": "missed-detection rate MDR"}
    ax.set_xlabel(names.get(labels[0], labels[0]))
    ax.set_ylabel(names.get(labels[1], labels[1]))
    ax.set_title(title or "Pareto front")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
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
    fig = _figure(7.5, 4.0)
    ax = fig.add_subplot()
    ax.plot(t, statistic, lw=0.9, color="tab:blue", label="chart statistic $l_k$")
    ax.plot(t, ucl, lw=1.2, color="tab:red", ls="--", label="UCL")
    alarms = statistic > ucl
    ax.plot(t[alarms], statistic[alarms], ".", ms=3, color="tab:red", label="alarm")
    _finish_time_axes(ax, t, fault_mask, "$l_k$", title or "Chart on one test replication")
    return _save(fig, path)


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
    return _save(fig, path)


def optimisation_history(path: str | Path, records: Sequence[dict]) -> Path:
    """Hypervolume, archive size and best accuracy per generation."""
    fig = _figure(7.5, 4.0)
    axes = fig.subplots(1, 3)
    gen = [r["generation"] for r in records]
    for ax, key, label in zip(axes, ("hypervolume", "archive_size", "best_accuracy"),
                              ("hypervolume (ref 1.1, 1.1)", "archive size", "best 1 − FAR − MDR")):
        ax.plot(gen, [r[key] for r in records], lw=1.2)
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_xlabel("generation")
        ax.set_title(label, fontsize=9)
        ax.grid(alpha=0.3)
    return _save(fig, path)

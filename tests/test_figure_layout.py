"""Issue 32, the fixed part of a run: the figures' own layout (no constrained layout) keeps every text inside
the canvas and apart from the others, on the inputs a run gives: long wrapped titles, log and symlog charts,
tick labels like 0.00025 and an offset text 1e−5, the Pareto zoom with its inset, three objectives, one and
a hundred generations.

Each figure is drawn as it is saved (same renderer and dpi); what is checked is every text the draw drew."""
from __future__ import annotations

import numpy as np
import pytest

from mosd.app import figures as plots

LONG = "pca on data=table: " + ", ".join(f"parameter_{i} = {0.1 * i + 1e-4:.4g}" for i in range(9))


def _draw(monkeypatch, name: str, **kwargs):
    """The figure ``name`` draws (not saved), drawn once; the texts the draw drew with their boxes (pixels)."""
    from matplotlib.text import Text

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    getattr(plots, name)(path="unused.png", **kwargs)
    (fig,) = figures
    return fig, _drawn_texts(fig, monkeypatch, Text)


def _drawn_texts(fig, monkeypatch, Text):
    drawn = []
    original = Text.draw

    def spy(self, renderer):
        original(self, renderer)
        if self.get_visible() and self.get_text().strip():
            drawn.append((self, self.get_window_extent(renderer)))

    with monkeypatch.context() as patched:
        patched.setattr(Text, "draw", spy)
        fig.canvas.draw()
    return drawn


def _overlap(a, b, tol: float = 0.5) -> bool:
    return a.x0 < b.x1 - tol and b.x0 < a.x1 - tol and a.y0 < b.y1 - tol and b.y0 < a.y1 - tol


def problems(fig, drawn) -> list[str]:
    """What is wrong with a drawn figure: text outside the canvas, texts overlapping, a text on a panel not its
    own (the suptitle and the figure's legend on any), a panel's tight box outside the canvas."""
    from matplotlib.text import Text

    renderer = fig.canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    found = []

    def inside(box, what):
        if box.x0 < -0.5 or box.y0 < -0.5 or box.x1 > width + 0.5 or box.y1 > height + 0.5:
            found.append(f"{what} outside the {width:.0f}x{height:.0f} canvas: {box.bounds}")

    for text, box in drawn:
        inside(box, f"text {text.get_text()!r}")
    for i, (a, box_a) in enumerate(drawn):
        for b, box_b in drawn[i + 1:]:
            if _overlap(box_a, box_b):
                found.append(f"texts {a.get_text()!r} and {b.get_text()!r} overlap")
    panels = fig.axes  # an inset is a child of its panel, not in fig.axes
    own = {id(ax): {id(text) for text in ax.findobj(Text)} for ax in panels}  # ticks, titles, insets, legend
    for ax in panels:
        inside(ax.get_tightbbox(renderer), "a panel's tight box")
        for text, box in drawn:
            if id(text) not in own[id(ax)] and _overlap(box, ax.bbox):
                found.append(f"text {text.get_text()!r} lies on another panel")
        for legend in fig.legends:
            if _overlap(legend.get_window_extent(renderer), ax.get_tightbbox(renderer)):
                found.append("the figure's legend lies on a panel")
    return found


def _chart(kind: str, points: int = 500):
    rng = np.random.default_rng(7)
    t = np.arange(points) * 0.005
    mask = t >= t[points // 2]
    noise = rng.random(points)
    if kind == "log":         # a positive statistic 30 times above its limit after the fault
        return t, 0.01 + noise + 60 * mask, np.full(points, 2.0), mask
    if kind == "decade":      # a log axis spanning about one decade: its minor ticks are labelled too
        return t, 5.0 + noise + 55 * mask, np.full(points, 5.5), mask
    if kind == "symlog":      # a signed statistic rising far above its limit
        return t, rng.normal(size=points) - 500 * mask, np.full(points, 3.0), mask
    if kind == "small":       # tick labels 0.00025 ...
        return t, 2.5e-4 * noise + 1e-4 * mask, np.full(points, 2.8e-4), mask
    return t, 1e-5 * noise, np.full(points, 1.1e-5), mask  # "tiny": the labels share an offset text 1e−5


@pytest.mark.parametrize("kind", ["log", "decade", "symlog", "small", "tiny"])
def test_the_chart_keeps_every_text_inside_and_apart(monkeypatch, kind):
    t, statistic, ucl, mask = _chart(kind)
    assert plots.chart_scale(statistic, ucl) == {"log": "log", "decade": "log", "symlog": "symlog"}.get(kind, "linear")
    fig, drawn = _draw(monkeypatch, "chart_trace", t=t, statistic=statistic, ucl=ucl, fault_mask=mask,
                       title=LONG if kind in ("log", "tiny") else "short")
    assert problems(fig, drawn) == []
    texts = [text.get_text() for text, _ in drawn]
    if kind == "log":
        assert fig.axes[0].title.get_text().count("\n") >= 1  # the long title is on several lines, all drawn
    if kind == "tiny":
        assert any("10^{−5}" in s or "10^{-5}" in s or "e-5" in s or "e−5" in s for s in texts), texts
    if kind == "small":
        assert "0.00025" in texts, texts
    if kind == "decade":
        assert sum("times" in s for s in texts) >= 2, texts  # minor labels: 2×10^1, 3×10^1 ...


def test_the_residual_keeps_a_long_title_inside(monkeypatch):
    rng = np.random.default_rng(1)
    residual = rng.normal(size=2000) * 1e-3
    mask = np.arange(2000) >= 1000
    fig, drawn = _draw(monkeypatch, "residual_trace", residual=residual, fault_mask=mask, dt=0.001,
                       sigma=1e-3, channel_name="x_p", title=LONG + " " + LONG)
    assert problems(fig, drawn) == []
    # nothing of the title is lost to the re-wrapping
    assert fig.axes[0].title.get_text().split() == (LONG + " " + LONG).split()


@pytest.mark.parametrize("zoom", [True, False])
def test_the_pareto_front_keeps_its_legend_below_and_its_inset_inside(monkeypatch, zoom):
    far = np.array([0.0, 2e-4, 8e-4, 1.4e-3, 2.4e-3, 6e-3, 0.02, 0.18, 0.32])
    mdr = np.array([1.8e-3, 1.6e-3, 1.4e-3, 1.2e-3, 1e-3, 8e-4, 6e-4, 4e-4, 1e-5])
    F = np.column_stack([far, mdr]) if zoom else np.array([[0.01, 0.2], [0.05, 0.08]])
    fig, drawn = _draw(monkeypatch, "pareto_front", F=F, chosen=0,
                       title="Archive of mopso on a rather long subject name (training replications)")
    assert problems(fig, drawn) == []
    ax = fig.axes[0]
    assert bool(ax.child_axes) == zoom
    renderer = fig.canvas.get_renderer()
    legend = fig.legends[0].get_window_extent(renderer)
    assert legend.y1 <= ax.get_tightbbox(renderer).y0  # below the axes, their labels included
    for inset in ax.child_axes:
        assert ax.bbox.contains(*inset.get_tightbbox(renderer).p0) and ax.bbox.contains(
            *inset.get_tightbbox(renderer).p1)


def test_pareto_pairs_keeps_its_three_panels_apart(monkeypatch):
    rng = np.random.default_rng(2)
    F = rng.random((30, 3)) * np.array([1e-4, 1.0, 250.0])
    fig, drawn = _draw(monkeypatch, "pareto_pairs", F=F, chosen=3, labels=("far", "mdr", "delay (s)"),
                       title="Archive of nsga2 over three objectives (training replications)")
    assert len(fig.axes) == 3
    assert problems(fig, drawn) == []


def _records(generations: int):
    rng = np.random.default_rng(generations)
    return [{"generation": g, "n_eval": 100 * g, "hypervolume": 1.2 - 0.3 / g + 1e-4 * rng.random(),
             "archive_size": 5 + g % 7, "best_accuracy": 0.99 - 0.2 / g} for g in range(1, generations + 1)]


@pytest.mark.parametrize("generations", [1, 100])
def test_the_history_keeps_its_three_panels_and_title_apart(monkeypatch, generations):
    title = ("mopso on data=a_recording_with_a_long_name_from_the_plant_historian: "
             f"{generations} generations, {100 * generations} evaluations (training replications)")
    fig, drawn = _draw(monkeypatch, "optimisation_history", records=_records(generations), title=title)
    assert len(fig.axes) == 3
    assert problems(fig, drawn) == []
    assert fig.get_suptitle().split() == title.split()


def test_the_check_sees_a_clipped_or_crowded_layout(monkeypatch):
    # the checks above must be able to fail: the same figures with margins too small
    fig, drawn = _draw(monkeypatch, "optimisation_history", records=_records(100), title="t")
    fig.subplots_adjust(left=0.01, wspace=0.02)
    from matplotlib.text import Text

    found = problems(fig, _drawn_texts(fig, monkeypatch, Text))
    assert any("outside the" in p for p in found) and any("overlap" in p or "another panel" in p for p in found)
    t, statistic, ucl, mask = _chart("log")
    fig, drawn = _draw(monkeypatch, "chart_trace", t=t, statistic=statistic, ucl=ucl, fault_mask=mask, title=LONG)
    fig.subplots_adjust(top=0.97, bottom=0.05)
    found = problems(fig, _drawn_texts(fig, monkeypatch, Text))
    assert any("outside the" in p for p in found), found


def test_the_axis_labels_stand_where_matplotlib_would_place_them(monkeypatch):
    # the layout places the axis labels itself (the draw's own search measures the ticks once more):
    # the same place to a pixel, on a log chart and on the history's panels
    from matplotlib.axis import Axis

    def drawn_labels():
        t, statistic, ucl, mask = _chart("log")
        boxes = []
        for name, kwargs in (("chart_trace", dict(t=t, statistic=statistic, ucl=ucl, fault_mask=mask)),
                             ("optimisation_history", dict(records=_records(100)))):
            fig, _ = _draw(monkeypatch, name, **kwargs)
            renderer = fig.canvas.get_renderer()
            boxes += [np.array(axis.label.get_window_extent(renderer).bounds) for ax in fig.axes
                      for axis in (ax.xaxis, ax.yaxis)]
        return np.array(boxes)

    placed = drawn_labels()
    with monkeypatch.context() as searched:
        searched.setattr(Axis, "set_label_coords", lambda self, x, y, transform=None: None)
        found = drawn_labels()
    np.testing.assert_allclose(placed, found, atol=1.0)

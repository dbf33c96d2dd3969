"""Model files written by mosd before the one generic pipeline, loaded as :class:`~mosd.streaming.OnlinePipeline`.

Runs logged before carry ``chart_detector.npz`` (the main command's monitor and chart) or
``pca_detector.npz`` (a recorded-data PCA) as their model's artifact; nothing a user logged is lost,
so :func:`mosd.app.detector_model.load_fitted` reads them into the same stages a new run saves.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..streaming import OnlinePipeline

_MEAN_VARIANCE = ("SSDEWMA", "SSEWMA", "MDEWMA", "MaxEWMA")


def _read(path: Path) -> tuple[dict, dict]:
    with np.load(path, allow_pickle=False) as f:
        return {k: f[k] for k in f.files if k != "meta"}, json.loads(str(f["meta"]))


def load_legacy(path: str | Path) -> OnlinePipeline:
    """The pipeline of an old ``chart_detector.npz`` or ``pca_detector.npz``."""
    from ..detectors.step import legacy_stage
    from ..detectors.latent_stage import legacy_online_pca
    from ..monitors.step import LEGACY as LEGACY_MONITORS

    path = Path(path)
    arrays, meta = _read(path)
    fill = meta.pop("fill", "none")
    if path.name == "chart_detector.npz":
        columns = tuple(str(c) for c in arrays["columns"])
        n = int(meta["n"])
        monitor = LEGACY_MONITORS["mosd.monitors.subgroups.OnlineSubgroups"]({   # the monitor stage such files named
            "columns": columns, "mean": arrays["mean"], "std": arrays["std"], "subgroup": meta["subgroup"], "n": n,
            "burn_in": int(meta["burn_in"])})
        if meta["chart"] == "EWMA":
            detector, design = "mosd.detectors.ewma_chart.EWMA", {"lam": meta["lam"], "L": meta["K"]}
        else:
            detector, design = f"mosd.detectors.mean_variance.{meta['chart']}", {"lam": meta["lam"], "K": meta["K"]}
        chart = legacy_stage("mosd.detectors.chart.OnlineChart", {   # the chart stage such files named
            "detector": detector, "design": {**design, "limit": meta["limit"]},
            "limit_value": float(meta["limit_value"]), "n": n, "denoiser": {}})
        return OnlinePipeline([monitor, chart], fill=fill)
    tags = tuple(str(t) for t in arrays.pop("tags"))
    pca = legacy_online_pca({"tags": tags, **arrays, **meta})   # the generic stage of the same PCA
    select = LEGACY_MONITORS["mosd.monitors.outputs.OnlineSelect"]({"columns": tags, "burn_in": 0})
    return OnlinePipeline([select, pca], fill=fill)

"""Sections of :mod:`mosd.bench` kept apart to keep that module short: the Tennessee Eastman families beside
their libraries (:func:`bench_tep_nonlinear`), the logged model's scoring speed beside bibmon's
(:func:`with_monitor`), and the OPC UA monitor's latency and load (:func:`bench_opcua`). ``python -m mosd.bench``
runs them by section name as before; the table rows and JSON keys are unchanged.
"""
from __future__ import annotations

import os
import time

import numpy as np


def bench_tep_nonlinear(quick: bool = False) -> tuple[list, dict]:
    """ICA, kernel PCA and autoencoder designs per second on the TE training split, and fit + score of the 22 test
    files beside the library's own fit + transform of the same model on the same rows (scikit-learn's FastICA and
    KernelPCA, PyTorch's training and forward pass), on one BLAS thread as mosd's fits (a multi-threaded FastICA
    took 64 s instead of 7 s on a 2-core machine at load average 12: threads spinning for cores others hold).

    Designs are drawn in each family's box (the preset's α box). ICA's fit does not depend on a design and is
    made before the clock starts (as PCA's); a kernel width or a network size is a new fit, inside the time.
    A family listed in :data:`mosd.systems.tep.FAMILIES` is timed by :func:`mosd.systems.tep.family_benchmark`
    instead (the same two figures); the library's time is added here either way.
    Figures: ``tep_candidates_per_s_<family>``, ``tep_fit_score_s_<family>`` and
    ``tep_library_fit_transform_s_<family>``.
    """
    import warnings

    from .data.tep import TennesseeEastman
    from .detectors.autoencoder import AutoencoderDetector
    from .detectors.ica import ICADetector
    from .detectors.kpca import KernelPCADetector
    from .detectors.pca import _one_blas_thread
    from .estimators.measured import MeasuredSignals
    from .monitors.outputs import OutputMonitor
    from .recorded import RecordedExperiment
    from .systems.tep import FAMILIES

    te = TennesseeEastman()
    calibration, test = te.trace("calibration").y, te.trace("test").y
    fit_rows, test_rows = calibration[0], test.reshape(-1, test.shape[-1])
    rng = np.random.default_rng(0)
    n = 6 if quick else 20
    common = [rng.uniform(1e-4, 0.1, n), rng.uniform(0.01, 1.0, n), rng.integers(1, 11, n)]
    families = {
        "ica": (ICADetector(fit_runs=1, max_components=32), [rng.integers(1, 33, n)]),
        "kpca": (KernelPCADetector(fit_runs=1, max_components=32), [rng.integers(1, 33, n), rng.integers(1, 1001, n)]),
        "autoencoder": (AutoencoderDetector(fit_runs=1, max_components=32, epochs=200),
                        [rng.integers(1, 33, n), rng.integers(4, 33, n), rng.integers(50, 301, n)]),
    }
    libraries = {"ica": _fastica_fit_transform, "kpca": _kernelpca_fit_transform, "autoencoder": _torch_fit_forward}
    rows, figures = [], {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # FastICA's non-convergence on TE (mosd.detectors.ica)
        for name, (detector, own) in families.items():
            if name not in FAMILIES:  # else family_benchmark has timed it (the same figures, its protocol)
                experiment = RecordedExperiment(te, MeasuredSignals(), OutputMonitor(), detector)
                evaluator = experiment.evaluator(experiment.prepare())
                X = np.column_stack([*own, *common]).astype(float)
                evaluator(detector.design())  # imports and the default design's fit
                start = time.perf_counter()
                evaluator(X)
                per_s = n / (time.perf_counter() - start)
                start = time.perf_counter()
                detector.decide(calibration, test)
                fit_score = time.perf_counter() - start
                load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
                rows += [(f"{name} designs/s on the training split, fits included", per_s,
                          f"{n} designs; load average {load:.1f}"),
                         (f"{name}: fit on d00.dat + score all 22 test files, s", fit_score, "default design")]
                figures.update({f"tep_candidates_per_s_{name}": per_s, f"tep_fit_score_s_{name}": fit_score})
            with _one_blas_thread():  # as mosd's own fits: the comparison is of the code, not of BLAS threads
                library = libraries[name](fit_rows, test_rows)
            rows.append((f"{name}: the library's own fit + transform of the same rows, s", library,
                         {"ica": "FastICA", "kpca": "KernelPCA", "autoencoder": "torch training + forward"}[name]))
            figures[f"tep_library_fit_transform_s_{name}"] = library
    return rows, figures


def _standardised(fit_rows, test_rows):
    mean, scale = fit_rows.mean(0), fit_rows.std(0, ddof=1)
    return (fit_rows - mean) / scale, (test_rows - mean) / scale


def _fastica_fit_transform(fit_rows, test_rows) -> float:
    from sklearn.decomposition import FastICA

    Z, T = _standardised(fit_rows, test_rows)
    start = time.perf_counter()
    FastICA(whiten="unit-variance", random_state=0, max_iter=1000, tol=1e-4).fit(Z).transform(T)
    return time.perf_counter() - start


def _kernelpca_fit_transform(fit_rows, test_rows) -> float:
    from sklearn.decomposition import KernelPCA

    Z, T = _standardised(fit_rows, test_rows)
    start = time.perf_counter()
    KernelPCA(n_components=32, kernel="rbf", gamma=1.0 / (10 * Z.shape[1]), eigen_solver="dense").fit(Z).transform(T)
    return time.perf_counter() - start


def _torch_fit_forward(fit_rows, test_rows) -> float:
    import torch

    from .detectors.autoencoder import LAYERS, _train

    Z, T = _standardised(fit_rows, test_rows)
    start = time.perf_counter()
    (weights, _), = _train(Z, 8, 24, [200], 0.01, 0)
    w = {k: torch.as_tensor(weights[k]) for k in LAYERS}
    with torch.no_grad():
        t = torch.tanh(torch.as_tensor(T) @ w["w1"] + w["b1"]) @ w["w2"] + w["b2"]
        torch.tanh(t @ w["w3"] + w["b3"]) @ w["w4"] + w["b4"]
    return time.perf_counter() - start


def with_monitor(r: dict, quick: bool) -> tuple[list, dict]:
    """bench_tep's rows and figures plus the logged model's scoring speed beside bibmon's (mosd.app.detector_model)."""
    from .app.model_bench import monitor_benchmark

    m = monitor_benchmark(quick)
    load = f"load average {m['load_average_1min_before']:.1f} -> {m['load_average_1min_after']:.1f}"
    rows = [("PCA designs/s on the training split, in-process", r["candidates_per_s"],
             f"{r['n_candidates']} designs, {r['training_points']} points each"),
            ("fit on d00.dat + score all 22 test files, s", r["fit_score_s"], f"{r['test_points']} points"),
            ("logged model: rows scored/s (predict on a DataFrame, in-process)", m["monitor_rows_per_s"],
             f"{m['rows']} TE test rows; T², SPE, EWMA, alarms, top-3 contributors; {load}"),
            ("logged model without top contributors, rows/s", m["monitor_no_top_rows_per_s"], "same rows, in turns"),
            ("floor: standardise + one projection + T², SPE sums, rows/s", m["t2_spe_floor_rows_per_s"],
             "float array in, two arrays out, one BLAS thread")]
    figures = {"tep_candidates_per_s": r["candidates_per_s"], "tep_fit_score_s": r["fit_score_s"],
               "monitor_rows_per_s": m["monitor_rows_per_s"], "monitor_no_top_rows_per_s": m["monitor_no_top_rows_per_s"],
               "t2_spe_floor_rows_per_s": m["t2_spe_floor_rows_per_s"],
               "monitor_load_average_1min": m["load_average_1min_after"]}
    for family, speed in r.get("families", {}).items():  # issue 29: every monitor family on the same rows
        rows.append((f"{family} designs/s on the training split", speed["candidates_per_s"],
                     f"fit + score of the 22 test files {speed['fit_score_s']:.3f} s"))
        figures[f"tep_candidates_per_s_{family}"] = speed["candidates_per_s"]
        figures[f"tep_fit_score_s_{family}"] = speed["fit_score_s"]
    if "bibmon_rows_per_s" in m:
        rows += [("bibmon PCA predict on the same rows, rows/s", m["bibmon_rows_per_s"],
                  f"in turns; SPE equal to {m['bibmon_spe_max_relative_difference']:.1e} relative"),
                 ("logged model / bibmon predict", m["monitor_rows_per_s"] / m["bibmon_rows_per_s"], "target >= 10"),
                 ("logged model without top / bibmon predict", m["monitor_no_top_rows_per_s"] / m["bibmon_rows_per_s"],
                  "target >= 10"),
                 ("floor / bibmon predict", m["t2_spe_floor_rows_per_s"] / m["bibmon_rows_per_s"],
                  "no scoring of T² and SPE can beat this ratio")]
        figures.update(bibmon_predict_rows_per_s=m["bibmon_rows_per_s"],
                       monitor_speedup_vs_bibmon=m["monitor_rows_per_s"] / m["bibmon_rows_per_s"],
                       monitor_no_top_speedup_vs_bibmon=m["monitor_no_top_rows_per_s"] / m["bibmon_rows_per_s"],
                       t2_spe_floor_speedup_vs_bibmon=m["t2_spe_floor_rows_per_s"] / m["bibmon_rows_per_s"],
                       # the same SPE (a flag: the JSON's 6 decimals would print 2e-14 as 0)
                       bibmon_spe_agrees=int(m["bibmon_spe_max_relative_difference"] < 1e-9))
    return rows, figures


def bench_opcua(quick: bool = False) -> tuple[list, dict]:
    """``mosd monitor --opcua`` against the replay server on 127.0.0.1 (:func:`mosd.live.bench.opcua_bench`):
    latency from a row's last tag write to its alarm node's write at 1 Hz x 100 tags, and sustained tag-samples/s."""
    try:
        from .live.bench import opcua_bench

        r = opcua_bench(quick)
    except Exception as exc:  # no asyncua, or no server: a row that says so, no figure
        text = " ".join(str(exc).split())[:200]
        return [(f"skipped: {text}", float("nan"), "")], {}
    load = f"load average {r['opcua_load_average_1min']:.1f}"
    rows = [("latency, value change to alarm write, median ms", r["opcua_latency_ms_p50"],
             f"1 Hz x 100 tags, {r['opcua_latency_rows']} rows, publishing interval 2 ms; {load}"),
            ("latency, 99th percentile ms", r["opcua_latency_ms_p99"], "target <= 20"),
            ("sustained tag-samples/s, one monitor process", r["opcua_samples_per_s"],
             f"{r['opcua_load_rows']} rows x 100 tags as fast as the replay writes them; target >= 5,000"),
            ("the replay server's own writes, tag-samples/s", r["opcua_server_samples_per_s"],
             "same process as the bench: near the line above, the server is the bound"),
            ("alarm writes missing", r["opcua_alarm_writes_missing"], "0: every row scored and written back"),
            ("tag values missing at the monitor", r["opcua_values_missing"], "0: every value the server wrote arrived")]
    keys = ("opcua_latency_ms_p50", "opcua_latency_ms_p99", "opcua_samples_per_s")
    return rows, {k: r[k] for k in keys}

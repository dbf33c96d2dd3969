"""``python -m mosd.bench``: speed and quality, measured side by side in one run.

Every row is a ratio of two things timed in the same process, one after the
other, so machine noise hits both. Sections:

* ``candidates`` — chart-tuning candidate evaluations per second on the paper
  workload (1,000 subgroups of 5 per sequence, SS-DEWMA, wavelet on, Phase-I
  limit, FAR and MDR): the compiled fused kernel (:mod:`mosd.kernels`) against
  the NumPy vectorised population (the reference path, same process, checked
  bit-identical) and a naive per-candidate Python loop; then the same chart
  without the wavelet (the app's default, ``denoise=none``), compiled against
  NumPy; each timing is the shortest of a few repeats;
* ``filter`` — CESCKF replication-steps per second: the compiled kernel
  (threads, and one thread) against the NumPy reference, batched and one
  replication at a time; paper 001's IMM batched against one run at a time;
* ``parallel`` — wall time of n_jobs=2 against n_jobs=1 on the paper workload;
* ``main`` — wall time of the main command ``python -m mosd +fault=offset_var
  optimizer=mopso`` at paper scale, as a subprocess, run twice (the second with
  warm caches);
* ``zdt`` — hypervolume and IGD on ZDT1–3 at 10,000 evaluations (slow: minutes);
* ``tuning`` — hypervolume of MOPSO against NSGA-II on the paper's (λ, K) problem
  at equal budget;
* ``tep`` — Tennessee Eastman PCA designs per second, and the logged model's
  scoring (rows/s, with and without the top contributors) beside BibMon's
  ``PCA.predict`` on the same rows, in turns;
* ``serve`` — ``mlflow models serve`` of a logged model on 127.0.0.1: the median
  latency of a request of 100 rows (the server is stopped afterwards).
* ``opcua`` — ``mosd monitor --opcua`` against the replay server on 127.0.0.1 (:mod:`mosd.live.bench`): the
  latency from a row's last tag write to the alarm node's write at 1 Hz × 100 tags (median and 99th
  percentile), and the tag-samples per second one monitor process sustains (a minute; ``--only opcua``);
* ``scale`` — one tuning per evaluation path (threads: the main command's chart; processes:
  paper 001's and 002's evaluators; recorded: TE PCA; the main command again at 20 times its
  training runs, ``threads_n200``) at n_jobs = 1, 2, 4, … up to the CPUs and
  on Dask at the largest: wall, serial, dispatch/gather and evaluation time per generation,
  speed-up, efficiency; then a sweep of 2 × CPUs jobs with the joblib launcher against one after
  the other (:mod:`mosd.app.scale_bench`; minutes; only with ``--only scale``).

Usage: ``python -m mosd.bench [--only candidates,filter,...] [--skip serve] [--quick] [--json]``.
``--json`` runs candidates, filter, parallel, main, tep and serve unless ``--only``
or ``--skip`` says otherwise, prints the table on stderr and one JSON object on stdout with
``candidates_per_s``, ``candidates_numpy_per_s``, ``candidates_speedup_vs_numpy``,
``candidates_speedup_vs_naive``, ``candidates_identical``, ``candidates_plain_per_s``,
``candidates_plain_speedup_vs_numpy``,
``parallel_speedup_2v1``, ``parallel_identical``, ``parallel_candidates_per_s``,
``filter_steps_per_s``, ``filter_speedup_vs_numpy`` (and their ``_one_thread`` forms), ``filter_numpy_steps_per_s``,
``filter_speedup_batched_vs_single``, ``imm_runs_per_s``, ``imm_numpy_runs_per_s``,
``imm_speedup_vs_numpy``, ``imm_speedup_batched_vs_single``, ``entropy_speedup_vs_numpy``, ``main_command_wall_s``,
``main_command_first_wall_s`` (of the sections run) and ``cpus``,
``load_average_1min`` (other load on the machine skews every ratio), ``quick``; ``tep`` (Tennessee Eastman,
:func:`mosd.systems.tep.benchmark`) adds ``tep_candidates_per_s``, ``tep_fit_score_s``,
``tep_candidates_per_s_<family>`` and ``tep_fit_score_s_<family>`` (:func:`mosd.systems.tep.family_benchmark`),
``monitor_rows_per_s``, ``monitor_no_top_rows_per_s``, ``t2_spe_floor_rows_per_s``, ``monitor_load_average_1min`` and,
with bibmon installed, ``bibmon_predict_rows_per_s``, ``monitor_speedup_vs_bibmon``, ``monitor_no_top_speedup_vs_bibmon``,
``t2_spe_floor_speedup_vs_bibmon``,
``bibmon_spe_agrees`` (1: the two SPEs agree to 1e-9 relative), and per family f in ica, kpca, autoencoder
``tep_candidates_per_s_f``, ``tep_fit_score_s_f``, ``tep_library_fit_transform_s_f``
(:func:`bench_tep_nonlinear`); ``serve`` adds ``serve_latency_ms`` and ``serve_latency_p90_ms``;
``opcua`` adds ``opcua_latency_ms_p50``, ``opcua_latency_ms_p99`` and ``opcua_samples_per_s``;
``scale`` adds ``scale_machine_ceiling_<n>`` (n copies of a loop that shares nothing at once against one: the
machine's own bound on any n-worker speed-up), ``scale_speedup_<workload>_<n>``,
``scale_compute_inflation_<workload>_<n>``,
``scale_serial_share_<workload>`` (the first generations), ``scale_serial_share_budget_<workload>`` (the set-up's
own run length; not with ``--quick``), ``scale_identical_<workload>``,
``scale_serial_move_ratio_<workload>`` (a MOPSO set-up: its serial time with the NumPy move over the compiled move's),
``scale_dask_vs_loky_<workload>``, ``scale_sweep_speedup``, ``scale_sweep_first_job_s`` and ``scale_load_average_1min``.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

from .bench_sections import bench_opcua, bench_tep_nonlinear, with_monitor  # noqa: F401 (sections by name)
from .timing import best_of

SECTIONS = ("candidates", "filter", "parallel", "main", "tuning", "zdt", "tep", "skab", "serve", "scale", "opcua")
DEFAULT_SECTIONS = ("candidates", "filter", "parallel", "tuning")
#: what ``--json`` runs by default: every section that feeds a JSON key
JSON_SECTIONS = ("candidates", "filter", "parallel", "main", "tep", "serve")


def benchmark_filter(
    n_reps: int = 100, n_steps: int = 5000, single_reps: int = 3, filter=None, seed: int = 0  # noqa: A002
) -> dict:
    """Replication-steps per second of a filter: compiled and NumPy, batched and one replication at a time.

    Simulates ``n_reps`` fault-free replications of the default mould
    oscillator (not timed), then filters them in one batched call four ways,
    one after the other in this process: the compiled kernel
    (:mod:`mosd.kernels.cubature`, its default threads, then one thread),
    the NumPy reference (``kernels.disabled()``), and the NumPy reference on
    ``single_reps`` replications one at a time (the loop over all ``n_reps``
    would take minutes; steps/s is what is compared). For a filter without a
    compiled form the compiled rows time the NumPy path.

    Returns
    -------
    dict
        filter, n_x, n_reps, n_steps, threads, batched_seconds,
        batched_steps_per_s (compiled, default threads), compiled_one_thread_steps_per_s,
        numpy_steps_per_s, single_reps, single_seconds, single_steps_per_s,
        speedup (NumPy batched / NumPy one at a time), speedup_vs_numpy,
        speedup_vs_numpy_one_thread, max_relative_difference (compiled vs NumPy, x̂_{k|k}).
    """
    from . import kernels
    from .estimators.residuals import _check_filter
    from .noise import GaussianNoise
    from .plants import MouldOscillator
    from .scenario import Scenario
    from .validation import check_int

    n_reps = check_int("n_reps", n_reps, 1)
    n_steps = check_int("n_steps", n_steps, 2)
    single_reps = check_int("single_reps", single_reps, 1)
    flt = _check_filter("estimator.filter", filter, None)
    plant = MouldOscillator()
    noise = GaussianNoise()
    trace = Scenario(plant, noise, fault=None, duration=n_steps * plant.dt).simulate(seed, n_reps, stream="calibration")
    model = plant.model(noise)
    flt.filter(model, trace.y[:1, :2], trace.u[:1, :2])  # load the compiled kernel outside the timing

    def timed():
        t0 = time.perf_counter()
        out = flt.filter(model, trace.y, trace.u)
        return time.perf_counter() - t0, out

    threads = kernels.threads()
    batched, compiled = timed()
    kernels.set_threads(1)
    try:
        one_thread, _ = timed()
    finally:
        kernels.set_threads(threads)
    with kernels.disabled():
        numpy_seconds, reference = timed()
        n_single = min(single_reps, n_reps)
        t0 = time.perf_counter()
        for r in range(n_single):
            flt.filter(model, trace.y[r : r + 1], trace.u[r : r + 1])
        single = time.perf_counter() - t0
    steps = n_reps * trace.n_samples
    single_rate = n_single * trace.n_samples / single
    scale = np.abs(reference.x_filt).max()
    return {
        "filter": repr(flt),
        "n_x": model.n_x,
        "n_reps": n_reps,
        "n_steps": trace.n_samples,
        "threads": threads,
        "batched_seconds": batched,
        "batched_steps_per_s": steps / batched,
        "compiled_one_thread_steps_per_s": steps / one_thread,
        "numpy_steps_per_s": steps / numpy_seconds,
        "single_reps": n_single,
        "single_seconds": single,
        "single_steps_per_s": single_rate,
        "speedup": (steps / numpy_seconds) / single_rate,
        "speedup_vs_numpy": numpy_seconds / batched,
        "speedup_vs_numpy_one_thread": numpy_seconds / one_thread,
        "max_relative_difference": float(np.abs(compiled.x_filt - reference.x_filt).max() / scale),
    }


def paper_workload(n_phase1: int = 10, n_train: int = 10, n_subgroups: int = 1000, n: int = 5, seed: int = 0,
                   a: float = 2.0, b: float = 2.0):
    """Standardised subgroups as the paper's simulation produces them (offset+variance fault).

    Residual subgroups are N(0, 1) in control and N(a, b²) from subgroup 501 on,
    like the paper's r ~ N(μ + aσ, b²σ²) with a = b = 2.
    """
    rng = np.random.default_rng(seed)
    phase1 = rng.standard_normal((n_phase1, n_subgroups, n))
    train = rng.standard_normal((n_train, n_subgroups, n))
    half = n_subgroups // 2
    train[:, half:] = a + b * train[:, half:]
    mask = np.zeros((n_train, n_subgroups), bool)
    mask[:, half:] = True
    return phase1, train, mask


def _paper_chart():
    from .detectors import SSDEWMA
    from .denoisers import WaveletDenoiser

    return SSDEWMA(lam=0.3, K=3.0, limit="phase1", denoiser=WaveletDenoiser(scaling="one"))


def _naive_objectives(chart, phase1, train, mask, x):
    """One candidate the obvious way: Python loops over sequences and time."""
    lam, K = x
    p = 1.0 - lam

    def statistic(z):
        u = math.sqrt(z.shape[-1]) * z.mean(axis=-1)
        from .detectors import subgroup_variance_statistic

        v = subgroup_variance_statistic(z)
        y = zz = w = q = 0.0
        out = []
        for uk, vk in zip(u, v):
            y = p * y + lam * uk
            zz = p * zz + lam * vk
            w = p * w + lam * y
            q = p * q + lam * zz
            out.append(w * w + q * q)
        return chart.denoiser.denoise(np.array(out)[None, :])[0]

    l1 = np.concatenate([statistic(z) for z in phase1])
    ucl = l1.mean() + K * l1.std(ddof=1)
    far, mdr = [], []
    for z, m in zip(train, mask):
        alarm = statistic(z) > ucl
        far.append(alarm[~m].mean())
        mdr.append((~alarm[m]).mean())
    return np.mean(far), np.mean(mdr)


def bench_candidates(quick: bool = False) -> tuple[list, dict]:
    from . import kernels
    from .denoisers import NoDenoiser
    from .optim.problem import CandidateEvaluator

    chart = _paper_chart()
    phase1, train, mask = paper_workload()
    evaluator = CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask)
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(0.01, 0.99, 100), rng.uniform(0.0, 5.0, 100)])
    F = evaluator(X)  # loads (or compiles) the kernels
    with kernels.disabled():
        reference = evaluator(X)
    repeats = 2 if quick else 5
    compiled = best_of(lambda: evaluator(X), repeats)
    with kernels.disabled():
        vectorised = best_of(lambda: evaluator(X), max(1, repeats // 2))
    n_naive = 2 if quick else 4
    t0 = time.perf_counter()
    naive_F = [_naive_objectives(chart, phase1, train, mask, x) for x in X[:n_naive]]
    naive = (time.perf_counter() - t0) / n_naive * len(X)
    np.testing.assert_allclose(F[:n_naive], naive_F, atol=2e-3)  # same numbers, up to rounding at the limit
    n_seq = train.shape[0]
    identical = bool(np.array_equal(F, reference))
    rows = [
        ("candidate evaluations/s, compiled (1 candidate x 1 training sequence, Phase-I limit included)",
         len(X) * n_seq / compiled, "target >= 25,000 on one core"),
        ("candidate evaluations/s, NumPy vectorised population (the reference path)", len(X) * n_seq / vectorised, ""),
        ("candidate evaluations/s, naive per-candidate Python loop", len(X) * n_seq / naive, ""),
        ("speed-up compiled / NumPy", vectorised / compiled, "target >= 10"),
        ("speed-up compiled / naive", naive / compiled, ""),
        ("compiled objectives identical to NumPy's", float(identical), "1 = yes"),
        ("sequences processed/s, compiled (Phase-I + training, 1,000 subgroups each)",
         len(X) * (n_seq + phase1.shape[0]) / compiled, ""),
    ]
    # the app's default chart (denoise=none): the recursion, the limit and the counts without the wavelet
    plain = _paper_chart()
    plain.denoiser = NoDenoiser()
    plain_evaluator = CandidateEvaluator(plain, plain.features(phase1), plain.features(train), mask)
    plain_F = plain_evaluator(X)
    plain_compiled = best_of(lambda: plain_evaluator(X), repeats)
    with kernels.disabled():
        plain_identical = bool(np.array_equal(plain_F, plain_evaluator(X)))
        plain_vectorised = best_of(lambda: plain_evaluator(X), max(1, repeats // 2))
    rows += [
        ("candidate evaluations/s, compiled, no denoiser (the app's default)", len(X) * n_seq / plain_compiled, ""),
        ("candidate evaluations/s, NumPy, no denoiser", len(X) * n_seq / plain_vectorised, ""),
        ("speed-up compiled / NumPy, no denoiser", plain_vectorised / plain_compiled,
         f"identical = {int(plain_identical)}"),
    ]
    metrics = {
        "candidates_plain_per_s": len(X) * n_seq / plain_compiled,
        "candidates_plain_speedup_vs_numpy": plain_vectorised / plain_compiled,
        "candidates_per_s": len(X) * n_seq / compiled,
        "candidates_numpy_per_s": len(X) * n_seq / vectorised,
        "candidates_speedup_vs_numpy": vectorised / compiled,
        "candidates_speedup_vs_naive": naive / compiled,
        "candidates_identical": int(identical),
    }
    return rows, metrics


def benchmark_imm(n_reps: int = 500, single_reps: int = 5, seed: int = 0) -> dict:
    """Paper 001's Monte Carlo: fused IMM estimates per second, compiled and NumPy, batched and one run at a time.

    The compiled kernel (:mod:`mosd.kernels.imm`) and the NumPy reference
    (``kernels.disabled()``) on the same ``n_reps`` runs, one after the other,
    then the reference on ``single_reps`` runs one at a time.
    """
    from . import kernels
    from .estimators.async_imm import AsyncIMMFusion
    from .faults.actuator import ActuatorFault
    from .noise.continuous import ContinuousWhiteNoise
    from .plants.networked_target import NetworkedTarget
    from .scenario import Scenario

    plant, noise = NetworkedTarget(), ContinuousWhiteNoise()
    model, imm = plant.model(noise), AsyncIMMFusion()
    trace = Scenario(plant, noise, ActuatorFault(), duration=41.0).simulate(seed, n_reps, stream="test")
    singles = [Scenario(plant, noise, ActuatorFault(), duration=41.0).simulate(seed, 1, stream="test", first=r)
               for r in range(single_reps)]
    imm.estimate(singles[0], model)  # load the compiled kernel outside the timing
    t0 = time.perf_counter()
    imm.estimate(trace, model)
    compiled = time.perf_counter() - t0
    with kernels.disabled():
        t0 = time.perf_counter()
        imm.estimate(trace, model)
        batched = time.perf_counter() - t0
        t0 = time.perf_counter()
        for one in singles:
            imm.estimate(one, model)
        single = time.perf_counter() - t0
    return {"n_reps": n_reps, "compiled_runs_per_s": n_reps / compiled, "batched_runs_per_s": n_reps / batched,
            "single_reps": single_reps, "single_runs_per_s": single_reps / single,
            "speedup": (n_reps / batched) / (single_reps / single), "speedup_vs_numpy": batched / compiled}


def benchmark_entropy(n_particles: int = 500, repeats: int = 20, seed: int = 0) -> dict:
    """Paper 002's entropy cost J, J′, J″ (two information potentials over the particle pairs): compiled vs NumPy."""
    from . import kernels
    from .estimators.entropy_filter import EntropyIsolationFilter

    rng = np.random.default_rng(seed)
    a1, b1, a2, b2 = rng.standard_normal((4, n_particles))
    filt = EntropyIsolationFilter()

    def one():
        return filt.cost(a1, b1, a2, b2, 0.4, 0.3, 0.5)

    one()  # load the compiled kernel outside the timing
    compiled = best_of(one, repeats)
    with kernels.disabled():
        reference = best_of(one, max(1, repeats // 4))
    return {"n_particles": n_particles, "compiled_per_s": 1.0 / compiled, "numpy_per_s": 1.0 / reference,
            "speedup_vs_numpy": reference / compiled}


def bench_filter(quick: bool = False) -> tuple[list, dict]:
    result = benchmark_filter(n_reps=20 if quick else 100, n_steps=1000 if quick else 5000)
    work = f"{result['n_reps']} replications x {result['n_steps']} steps, n_x = {result['n_x']}"
    rows = [
        ("CESCKF steps/s, compiled, batched", result["batched_steps_per_s"],
         f"{result['threads']} threads; target >= 500,000"),
        ("CESCKF steps/s, compiled, batched, one thread", result["compiled_one_thread_steps_per_s"], work),
        ("CESCKF steps/s, NumPy batched (the reference path)", result["numpy_steps_per_s"], ""),
        ("CESCKF steps/s, NumPy one replication at a time", result["single_steps_per_s"],
         f"{result['single_reps']} replications"),
        ("CESCKF speed-up compiled / NumPy batched", result["speedup_vs_numpy"], "target >= 5"),
        ("CESCKF speed-up compiled one thread / NumPy batched", result["speedup_vs_numpy_one_thread"], ""),
        ("CESCKF speed-up NumPy batched / one at a time", result["speedup"], ""),
        ("CESCKF compiled vs NumPy, max relative difference of x_filt", result["max_relative_difference"],
         "not bit-identical: LAPACK's QR sums in another order"),
    ]
    imm = benchmark_imm(n_reps=50 if quick else 500)
    rows += [("IMM (paper 001) runs/s, compiled, batched", imm["compiled_runs_per_s"],
              f"{imm['n_reps']} runs of 41 s, 3 sensors"),
             ("IMM runs/s, NumPy batched (the reference path)", imm["batched_runs_per_s"], ""),
             ("IMM runs/s, NumPy one run at a time", imm["single_runs_per_s"], f"{imm['single_reps']} runs"),
             ("IMM speed-up compiled / NumPy batched", imm["speedup_vs_numpy"], "same process"),
             ("IMM speed-up NumPy batched / one at a time", imm["speedup"], "same process")]
    entropy = benchmark_entropy()
    rows += [("entropy cost (paper 002) evaluations/s, compiled", entropy["compiled_per_s"],
              f"J, J', J'' over 2 x {entropy['n_particles']} particles"),
             ("entropy cost evaluations/s, NumPy (the reference path)", entropy["numpy_per_s"], ""),
             ("entropy speed-up compiled / NumPy", entropy["speedup_vs_numpy"], "same process")]
    metrics = {
        "imm_runs_per_s": imm["compiled_runs_per_s"],
        "imm_numpy_runs_per_s": imm["batched_runs_per_s"],
        "imm_speedup_vs_numpy": imm["speedup_vs_numpy"],
        "imm_speedup_batched_vs_single": imm["speedup"],
        "entropy_speedup_vs_numpy": entropy["speedup_vs_numpy"],
        "filter_steps_per_s": result["batched_steps_per_s"],
        "filter_steps_per_s_one_thread": result["compiled_one_thread_steps_per_s"],
        "filter_numpy_steps_per_s": result["numpy_steps_per_s"],
        "filter_speedup_vs_numpy": result["speedup_vs_numpy"],
        "filter_speedup_vs_numpy_one_thread": result["speedup_vs_numpy_one_thread"],
        "filter_speedup_batched_vs_single": result["speedup"],
    }
    return rows, metrics


def _tuning_setup(n_jobs: int, a: float = 2.0, b: float = 2.0):
    from .optim.problem import CandidateEvaluator, TuningProblem

    chart = _paper_chart()
    phase1, train, mask = paper_workload(a=a, b=b)
    evaluator = CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask)
    return TuningProblem(evaluator, bounds={"K": (0.0, 5.0)}, n_jobs=n_jobs)


def bench_parallel(quick: bool = False) -> tuple[list, dict]:
    from pymoo.optimize import minimize

    from .optim import MOPSO

    n_gen = 5 if quick else 20
    times = {}
    results = {}
    for n_jobs in (1, 2):
        problem = _tuning_setup(n_jobs)
        problem.evaluate_population(np.array([[0.3, 1.0], [0.4, 2.0]]))  # start the pool outside the timing
        best = math.inf
        for _ in range(1 if quick else 4):  # the shortest of four runs: the one the rest of the machine disturbed least
            t0 = time.perf_counter()
            res = minimize(problem, MOPSO.paper(pop_size=100), ("n_gen", n_gen), seed=1)
            best = min(best, time.perf_counter() - t0)
        times[n_jobs] = best
        results[n_jobs] = res.F
        problem.close()
    same = results[1].shape == results[2].shape and np.array_equal(results[1], results[2])
    evals = 100 * n_gen * 10
    rows = [
        ("wall time n_jobs=1 (s)", times[1], f"MOPSO 100 x {n_gen}"),
        ("wall time n_jobs=2 (s)", times[2], ""),
        ("speed-up n_jobs=2 vs 1", times[1] / times[2], "target >= 1.8"),
        ("candidate evaluations/s on 2 cores", evals / times[2], "target >= 50,000"),
        ("identical archives for n_jobs 1 and 2", float(same), "1 = yes"),
    ]
    metrics = {
        "parallel_speedup_2v1": times[1] / times[2],
        "parallel_identical": int(same),
        "parallel_candidates_per_s": evals / times[2],
    }
    return rows, metrics


def main_command_wall(args: tuple[str, ...] = ("+fault=offset_var", "optimizer=mopso"), runs: int = 2,
                      extra: tuple[str, ...] = ()) -> list[float]:
    """Wall seconds of ``python -m mosd ARGS`` as a subprocess, ``runs`` times in a row (later runs: warm caches).

    Run directories and the MLflow store go to a temporary directory (MOSD_OUTPUTS), removed afterwards.
    """
    import subprocess
    import tempfile

    walls = []
    with tempfile.TemporaryDirectory(prefix="mosd-bench-") as outputs:
        env = dict(os.environ, MOSD_OUTPUTS=outputs)
        for _ in range(runs):
            t0 = time.perf_counter()
            done = subprocess.run([sys.executable, "-m", "mosd", *args, *extra], env=env, capture_output=True,
                                  text=True)
            walls.append(time.perf_counter() - t0)
            if done.returncode != 0:
                raise RuntimeError(f"python -m mosd {' '.join(args + extra)} failed: {done.stderr.strip()[-500:]}")
    return walls


def bench_main(quick: bool = False) -> tuple[list, dict]:
    extra = ("optimizer.n_gen=5", "budget.n_test=10") if quick else ()
    walls = main_command_wall(extra=extra)
    command = "python -m mosd +fault=offset_var optimizer=mopso" + (" " + " ".join(extra) if extra else "")
    rows = [
        (f"main command wall time, first run (s): {command}", walls[0], "cold: may compile the kernels"),
        ("main command wall time, second run (s)", walls[1], "target <= 5 s warm"),
    ]
    return rows, {"main_command_wall_s": walls[1], "main_command_first_wall_s": walls[0]}


def bench_tuning(quick: bool = False) -> list[tuple[str, float, str]]:
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.optimize import minimize

    from .metrics.summary import hypervolume
    from .optim import MOPSO

    # A small fault (0.25σ offset, σ × 1.1): the paper's 2σ faults are separated perfectly
    # at n = 5 (both algorithms reach FAR = MDR = 0), which would compare nothing.
    problem = _tuning_setup(1 if quick else 2, a=0.25, b=1.1)
    n_gen = 10 if quick else 50
    seeds = (1, 2) if quick else (1, 2, 3)
    rows = []
    try:
        for name, make in (("MOPSO", lambda: MOPSO(pop_size=100)), ("MOPSO (paper)", lambda: MOPSO.paper(pop_size=100)),
                           ("NSGA-II", lambda: NSGA2(pop_size=100))):
            values = [hypervolume(minimize(problem, make(), ("n_gen", n_gen), seed=s).F) for s in seeds]
            rows.append((f"hypervolume (FAR, MDR) {name}, median of {len(seeds)} seeds", float(np.median(values)),
                         f"100 x {n_gen}, ref (1.1, 1.1), fault a=0.25, b=1.1"))
    finally:
        problem.close()
    rows.append(("hypervolume ratio MOPSO / NSGA-II", rows[0][1] / rows[1][1], ""))
    return rows


def bench_zdt(quick: bool = False) -> list[tuple[str, float, str]]:
    """Median hypervolumes of the MOPSO presets, NSGA-II, SMPSO (jMetalPy) and MOPSO_CD, and the ratios.

    The full benchmark is ``python -m mosd.optim.benchmarks`` (ZDT1–4, ZDT6, DTLZ2); here ZDT1–3 and
    DTLZ2, every algorithm run side by side at equal evaluations (docs/MOPSO.md).
    """
    from .optim.benchmarks import DEFAULT_NAME, NSGA2_NAME, SMPSO_NAME, benchmark_table

    n_seeds = 2 if quick else 5
    table = benchmark_table(problems=("zdt1", "zdt2", "zdt3", "dtlz2"), seeds=tuple(range(1, n_seeds + 1)),
                            n_eval=2000 if quick else 10_000, n_jobs=2)
    rows = []
    hv = {(row["problem"], row["algorithm"]): row["hv_median"] for row in table}
    for row in table:
        rows.append((f"{row['problem']} {row['algorithm']} hypervolume", row["hv_median"],
                     f"median of {n_seeds} seeds"))
    for problem in dict.fromkeys(row["problem"] for row in table):
        for reference in (SMPSO_NAME, NSGA2_NAME):
            if (problem, reference) in hv and hv[(problem, reference)] > 0:
                rows.append((f"{problem} {DEFAULT_NAME} / {reference}",
                             hv[(problem, DEFAULT_NAME)] / hv[(problem, reference)], "ratio, same run"))
    return rows


def bench_tep(quick: bool = False) -> tuple[list, dict]:
    """PCA designs per second on the TE training split; fit + score of the 22 test files (mosd.systems.tep)."""
    from .data.tep import bibmon_directory
    from .systems.tep import benchmark

    if bibmon_directory() is None:
        return [("skipped: the TE files need pip install \".[te]\"", float("nan"), "")], {}
    rows, figures = with_monitor(benchmark(quick), quick)
    family_rows, family_figures = bench_tep_nonlinear(quick)
    return rows + family_rows, {**figures, **family_figures}


def bench_skab(quick: bool = False) -> tuple[list, dict]:
    """SKAB under its protocol (mosd.systems.skab): every family's 5-fold CV and one family's, wall seconds.

    Needs SKAB's data folder in ``MOSD_SKAB`` (GPL-3.0: never shipped); the issue's targets are all families
    within 10 minutes and one within 2 on 2 cores. ``--quick``: DPCA alone.
    """
    import io

    from .systems.skab import study
    from .systems.skab_study import FAMILIES

    root = os.environ.get("MOSD_SKAB", "").strip()
    if not root or not os.path.isdir(root):
        return [("skipped: MOSD_SKAB does not name SKAB's data folder", float("nan"), "")], {}
    rows, figures = [], {}
    for label, families in (("dpca", ("dpca",)), *(() if quick else (("families", FAMILIES),))):
        t0 = time.perf_counter()
        result = study(root, families, seed=0, log=io.StringIO())
        seconds = time.perf_counter() - t0
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
        rows.append((f"{label}: 34 experiments, 5-fold CV, 5 budgets, s", seconds,
                     f"{len(families)} famil{'y' if len(families) == 1 else 'ies'} + the T²+Q row; load {load:.1f}"))
        figures[f"skab_{label}_s"] = seconds
    return rows, figures


def bench_serve(quick: bool = False) -> tuple[list, dict]:
    """``mlflow models serve`` of a logged model: median latency of a request of 100 rows (mosd.app.detector_model)."""
    from .app.model_bench import serve_benchmark

    try:
        r = serve_benchmark(quick)
    except RuntimeError as exc:  # no server: a row that says so, no figure
        return [(f"skipped: {exc}", float("nan"), "")], {}
    note = (f"{r['serve_requests']} requests of {r['serve_rows_per_request']} {r['serve_source']}, state carried; "
            f"load average {r['load_average_1min']:.1f}")
    rows = [("served latency per request of 100 rows, median ms", r["serve_latency_ms"], note),
            ("served latency, 90th percentile ms", r["serve_latency_p90_ms"], ""),
            ("server start until /ping answers, s", r["serve_start_s"], "mlflow models serve --env-manager local")]
    return rows, {"serve_latency_ms": r["serve_latency_ms"], "serve_latency_p90_ms": r["serve_latency_p90_ms"]}


def bench_scale(quick: bool = False) -> tuple[list, dict]:
    """Speed-up, serial share and per-generation overhead per evaluation path (:mod:`mosd.app.scale_bench`)."""
    from .app.scale_bench import bench_scale as scale

    return scale(quick)


def main(argv: list[str] | None = None) -> int:
    import json

    parser = argparse.ArgumentParser(prog="python -m mosd.bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default=None,
                        help=f"comma-separated sections out of {', '.join(SECTIONS)} (zdt takes minutes); default "
                             f"{','.join(DEFAULT_SECTIONS)}, with --json {','.join(JSON_SECTIONS)}")
    parser.add_argument("--skip", default="", help="comma-separated sections to leave out (e.g. serve: it starts "
                        "an MLflow model server on 127.0.0.1)")
    parser.add_argument("--quick", action="store_true", help="smaller sizes, for a smoke run")
    parser.add_argument("--json", action="store_true",
                        help="also print one JSON object of the headline numbers on stdout (the table goes to stderr)")
    args = parser.parse_args(argv)
    only = args.only if args.only is not None else ",".join(JSON_SECTIONS if args.json else DEFAULT_SECTIONS)
    chosen = [s.strip() for s in only.split(",") if s.strip()]
    skipped = [s.strip() for s in args.skip.split(",") if s.strip()]
    unknown = [s for s in chosen + skipped if s not in SECTIONS]
    if unknown:
        print(f"error: --{'only' if unknown[0] in chosen else 'skip'} {unknown[0]!r} is unknown; allowed: "
              f"{', '.join(SECTIONS)}", file=sys.stderr)
        return 2
    chosen = [s for s in chosen if s not in skipped]
    table = sys.stderr if args.json else sys.stdout
    print(f"# mosd.bench — {os.cpu_count()} CPUs, numpy {np.__version__}; numbers are this machine's, this run's",
          file=table)
    print("| section | measure | value | note |\n|---|---|---:|---|", file=table)
    metrics: dict = {}
    for section in chosen:
        fn = globals()[f"bench_{section}"]
        t0 = time.perf_counter()
        out = fn(args.quick)
        rows, found = out if isinstance(out, tuple) else (out, {})
        metrics.update(found)
        for name, value, note in rows:
            print(f"| {section} | {name} | {value:,.4g} | {note} |", file=table, flush=True)
        print(f"| {section} | (section wall time, s) | {time.perf_counter() - t0:.1f} | |", file=table, flush=True)
    if args.json:
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
        metrics.update(cpus=os.cpu_count(), load_average_1min=load, quick=int(args.quick))
        print(json.dumps(json_metrics(metrics), allow_nan=False), flush=True)
    return 0


def json_metrics(metrics: dict) -> dict:
    """The ``--json`` line's keys: floats rounded to 6 decimals, and a value that is not a finite number left out.

    JSON has no NaN or infinity (``json.dumps`` would write bare ``NaN``, which strict parsers refuse): a figure
    the machine could not give (no load average, no sweep job log) is absent rather than written as one.
    """
    out = {}
    for key, value in metrics.items():
        if isinstance(value, (float, np.floating)):
            if not math.isfinite(value):
                continue
            value = round(float(value), 6)
        elif isinstance(value, np.integer):
            value = int(value)
        out[key] = value
    return out


if __name__ == "__main__":
    sys.exit(main())

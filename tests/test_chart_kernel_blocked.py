"""The chart kernel's blocked layout (issue 32) and the split evaluation the threaded tuning runs.

The kernel evaluates candidates side by side in blocks of lanes and sums the Phase-I mean and deviations
as the calibration points come (NumPy's pairwise order, no array of points); a population split into any
slices, each through ``counts_of`` (what a worker thread runs), gives the objectives of the whole, bit for
bit, and both equal the NumPy reference.
"""
import numpy as np
import pytest

from mosd import kernels
from mosd.denoisers import NoDenoiser, WaveletDenoiser
from mosd.detectors import MDEWMA, SSDEWMA, MaxEWMA
from mosd.detectors.fused import EvaluationPlan
from mosd.kernels import chart
from mosd.optim.problem import CandidateEvaluator

assert kernels.available(), "numba is a dependency of mosd"


def _evaluator(chart_type=SSDEWMA, denoiser=None, n_cal=3, n_train=4, n_points=203, seed=0):
    rng = np.random.default_rng(seed)
    phase1 = rng.standard_normal((n_cal, n_points, 5))
    train = rng.standard_normal((n_train, n_points, 5))
    onset = n_points // 2
    train[:, onset:] = 0.6 + 1.3 * train[:, onset:]
    mask = np.zeros((n_train, n_points), bool)
    mask[:, onset:] = True
    detector = chart_type(limit="phase1", denoiser=denoiser or NoDenoiser())
    return CandidateEvaluator(detector, detector.features(phase1), detector.features(train), mask)


def _population(size, seed=4):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(1e-3, 0.999, size), rng.uniform(0.0, 5.0, size)])


def _random_split(n, rng):
    """Cut points 0 = c0 < c1 < ... < cm = n, with slices of one candidate, of less than a block of lanes, of more."""
    cuts = sorted(set(rng.integers(1, n, size=rng.integers(1, 8)).tolist()))
    return [0, *cuts, n]


@pytest.mark.parametrize("chart_type, denoiser", [(SSDEWMA, None), (MaxEWMA, None), (MDEWMA, WaveletDenoiser())],
                         ids=["ss", "max", "order2-wavelet"])
def test_a_population_split_into_any_slices_gives_the_objectives_of_the_whole(chart_type, denoiser):
    evaluator = _evaluator(chart_type, denoiser)
    fused = evaluator.fused()
    assert fused is not None
    n = 2 * chart._LANES + 5  # two full blocks of lanes and a partial one
    X = _population(n)
    whole = fused(X)
    plan = fused.plan(X)
    assert isinstance(plan, EvaluationPlan) and len(plan) == n
    assert np.array_equal(whole, fused.objectives(*fused.counts_of(plan, 0, n)))
    assert np.array_equal(whole, evaluator.reference(X))
    rng = np.random.default_rng(11)
    for _ in range(4):
        cuts = _random_split(n, rng)
        parts = [fused.counts_of(plan, start, stop) for start, stop in zip(cuts[:-1], cuts[1:])]
        for (start, stop), (alarms, misses) in zip(zip(cuts[:-1], cuts[1:]), parts):
            assert alarms.shape == misses.shape == (stop - start, fused.faulty.shape[0])
            assert alarms.dtype == misses.dtype == np.int64
        alarms = np.concatenate([p[0] for p in parts])
        misses = np.concatenate([p[1] for p in parts])
        assert np.array_equal(fused.objectives(alarms, misses), whole), cuts


def test_counts_of_runs_in_threads_and_gives_the_same_counts():
    """``counts_of`` releases the GIL: slices evaluated on threads at once give the whole's counts."""
    from concurrent.futures import ThreadPoolExecutor

    fused = _evaluator(n_train=6, n_points=400).fused()
    X = _population(3 * chart._LANES)
    plan = fused.plan(X)
    alarms, misses = fused.counts_of(plan, 0, len(X))
    cuts = [0, 5, 21, 22, 40, len(X)]
    with ThreadPoolExecutor(3) as pool:
        parts = list(pool.map(lambda bounds: fused.counts_of(plan, *bounds), zip(cuts[:-1], cuts[1:])))
    assert np.array_equal(np.concatenate([p[0] for p in parts]), alarms)
    assert np.array_equal(np.concatenate([p[1] for p in parts]), misses)


@pytest.mark.parametrize("chart_type, denoiser", [(SSDEWMA, None), (MDEWMA, None), (MaxEWMA, WaveletDenoiser())],
                         ids=["ss", "order2", "max-wavelet"])
def test_a_short_block_computes_every_candidate_of_its_slice(chart_type, denoiser):
    """A block of fewer candidates than lanes computes only the lanes it needs (its candidates rounded up to
    ``chart._VECTOR``): every slice length from one candidate to a block and one, at a block's start and past
    it, gives the NumPy reference's objectives for its rows (a lane count rounded the wrong way, or state left
    over from the previous block in a lane now used, would not)."""
    evaluator = _evaluator(chart_type, denoiser, n_cal=2, n_train=3, n_points=97, seed=5)
    fused = evaluator.fused()
    assert fused is not None
    assert fused.lanes == chart._VECTOR and chart._LANES % fused.lanes == 0
    n = chart._LANES + 5
    X = _population(n + 3, seed=9)
    reference = evaluator.reference(X)
    plan = fused.plan(X)
    for start in (0, 3):
        for length in range(1, n - start + 1):
            counts = fused.counts_of(plan, start, start + length)
            assert np.array_equal(fused.objectives(*counts), reference[start:start + length]), (start, length)
    # a full block, then a short one in the same call: the short one's lanes held the full block's state
    counts = fused.counts_of(plan, 3, 3 + chart._LANES + 2)
    assert np.array_equal(fused.objectives(*counts), reference[3:5 + chart._LANES])


@pytest.mark.parametrize("n_cal, n_points", [(1, 2), (1, 7), (2, 9), (1, 128), (3, 43), (2, 1000), (7, 333)])
def test_the_streamed_pairwise_sums_give_the_reference_limit_for_any_number_of_points(n_cal, n_points):
    """The Phase-I mean and deviations, summed as the points come, in NumPy's pairwise order: blocks of fewer
    than eight values, of eight or more with a rest, several blocks with joins; the counts equal the NumPy
    path's (which fits the limit with np.mean and np.std) for every candidate."""
    evaluator = _evaluator(n_cal=n_cal, n_train=2, n_points=n_points, seed=n_points)
    X = _population(chart._LANES + 3, seed=n_cal)
    assert np.array_equal(evaluator(X), evaluator.reference(X))


def test_pairwise_leaves_reproduce_numpys_sum():
    """Summing the blocks of :func:`_pairwise_leaves` one after another and joining them as it says is
    NumPy's sum, bit for bit (the plan the kernel streams the calibration points through)."""
    from numba import njit

    @njit
    def summed(values):
        sizes, joins = chart._pairwise_leaves(values.shape[0])
        stack = np.empty(64)
        depth, start = 0, 0
        for leaf in range(sizes.shape[0]):
            stack[depth] = chart._pairwise_sum(values, start, sizes[leaf])
            depth += 1
            start += sizes[leaf]
            for _ in range(joins[leaf]):
                depth -= 1
                stack[depth - 1] = stack[depth - 1] + stack[depth]
        return stack[0], depth, start

    for n in (1, 7, 8, 129, 1000, 8193, 50000, 123457):
        values = np.random.default_rng(n).standard_normal(n) * 10.0 ** np.random.default_rng(n + 1).uniform(-3, 3, n)
        total, depth, consumed = summed(values)
        assert total == np.sum(values) and depth == 1 and consumed == n, n


@pytest.mark.slow
def test_the_kernel_compiles_each_helper_once(tmp_path):
    """Both kernels call the shared helpers with the same argument types (no literal flag, mode or size): one
    compiled version each, on an empty cache (a second per helper would cost the first run compile time)."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    import mosd

    env = {k: v for k, v in os.environ.items() if k != "MOSD_KERNELS"}
    env.update(NUMBA_CACHE_DIR=str(tmp_path), PYTHONPATH=str(Path(mosd.__file__).resolve().parents[1]))
    code = ("import json\nfrom mosd.kernels import chart\nchart.warm_up_all()\n"
            "print(json.dumps({f.py_func.__name__: len(f.signatures) for f in (chart._statistics, chart._accumulate,"
            " chart._count, chart._buffers, chart._lanes, chart._limits, chart._pairwise_leaves, chart.alarm_counts,"
            " chart.alarm_counts_denoised)}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    counts = json.loads(out.stdout.strip().splitlines()[-1])
    assert set(counts.values()) == {1}, counts

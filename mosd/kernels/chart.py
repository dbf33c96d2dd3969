"""The fused candidate evaluation of a mean–variance chart (SS-DEWMA and kin), compiled.

For one candidate (λ, K) and the features (U_k, V_k) of the calibration and the
training runs, the reference path (``Chart.population`` then
``objective_values``) computes the smoothed statistic of every run, denoises it,
fits the Phase-I limit E{l} + K·sd{l} on the calibration runs and scores the
training runs' alarms — materialising (P, R, K) statistics, limits and
decisions on the way. Here all of it is one compiled loop that returns per-run
alarm counts (P, R): healthy points that alarm and target-fault points that do not.

The loop is laid out for the memory, which bounded it once several threads ran
it (issue 32): candidates go through side by side, :data:`_LANES` at a time, so
each run's features are read once per block of candidates, not once per
candidate, and each time step's arithmetic is one vector loop over the block;
the features are run-major (each run's points contiguous); no statistic is
written out beyond a segment of :data:`_SEGMENT` points, as the Phase-I mean and
deviations are summed while the calibration points are produced (in NumPy's
pairwise order, :func:`_accumulate`) and the training points scored as they are.
A candidate's counts do not depend on the others in its block: each lane's
arithmetic is its candidate's alone, so a population split any way gives the
same counts. A block of fewer candidates computes only the lanes it needs (its
candidates rounded up to :data:`_VECTOR`), so a caller may split a population
into as many slices as it has threads: a slice of 6 to 8 costs 0.6-0.75 of a
full block, of 4 0.4-0.6, not a whole one (the rest is each step's latency).

Each step is the chart's own (:meth:`mosd.detectors.chart.Chart.scan`): the EWMA update
:func:`mosd.kernels.ewma.ewma_step` and the statistic :func:`mosd.kernels.ewma.combine_step`, called here
as there, the whole-series wavelet :func:`mosd.kernels.wavelet.denoise_row` the denoiser runs; the Phase-I
limit's sums are NumPy's pairwise summation (:func:`mean_std`, which ``fit_statistic`` calls) accumulated as
the points come. So FAR and MDR come out as the alarm counts of the chart's decisions;
``tests/test_kernels.py`` and ``tests/test_step_chart.py`` check it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile

from .ewma import COMBINE_MAX, COMBINE_SS, combine_step, ewma_step
from .wavelet import denoise_row, work_size

_BLOCK = 128  # NumPy's pairwise-summation block (PW_BLOCKSIZE)

#: a helper called only from compiled code: no CPython or C entry point to build (numba builds both for every
#: function it compiles, called from Python or not: on an empty cache each cost the main command compile time)
_helper = njit(cache=True, nogil=True, no_cpython_wrapper=True, no_cfunc_wrapper=True)


@_helper
def _pairwise_sum(a, start, n):
    """NumPy's pairwise summation of a[start:start + n] (what ``np.add.reduce`` does on a contiguous float64 array).

    NumPy recurses: sum(a[:h]) + sum(a[h:]) with h = n//2 rounded down to a
    multiple of 8, down to blocks of at most 128, each summed with eight
    accumulators, then the rest. The recursion's blocks and joins are
    :func:`_pairwise_leaves`' (numba's on-disk cache mishandles recursive
    functions); here each block is summed as it comes and the partial sums are
    joined on a stack. The block's sum is written once, in the loop, not as a
    function of its own (each compiled function costs the cold cache its own
    optimisation and code generation).
    """
    sizes, joins = _pairwise_leaves(n)
    values = np.empty(sizes.shape[0])
    depth = 0
    s = start
    for leaf in range(sizes.shape[0]):
        m = sizes[leaf]
        if m < 8:  # a block: NumPy's eight accumulators, then the rest
            res = 0.0
            for i in range(s, s + m):
                res += a[i]
        else:
            r0, r1, r2, r3 = a[s], a[s + 1], a[s + 2], a[s + 3]
            r4, r5, r6, r7 = a[s + 4], a[s + 5], a[s + 6], a[s + 7]
            i = 8
            stop = m - m % 8
            while i < stop:
                b = s + i
                r0 += a[b]
                r1 += a[b + 1]
                r2 += a[b + 2]
                r3 += a[b + 3]
                r4 += a[b + 4]
                r5 += a[b + 5]
                r6 += a[b + 6]
                r7 += a[b + 7]
                i += 8
            res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
            while i < m:
                res += a[s + i]
                i += 1
        values[depth] = res
        depth += 1
        s += m
        for _ in range(joins[leaf]):  # left + right, as the recursion returns
            depth -= 1
            values[depth - 1] = values[depth - 1] + values[depth]
    return values[0]


@njit(cache=True, nogil=True)
def mean_std(values):
    """(np.mean(values), np.std(values, ddof=1)) of a contiguous 1-D array, bit for bit.

    With a CPython entry point: the main command calls it from Python too (the deployed chart's Phase-I
    limit, ``fit_statistic``), so one compile serves both.
    """
    n = values.shape[0]
    center = _pairwise_sum(values, np.int64(0), n) / n  # an int64 start, not Literal[int](0): one compile
    deviations = np.empty(n)
    for i in range(n):
        d = values[i] - center
        deviations[i] = d * d
    return center, math.sqrt(_pairwise_sum(deviations, np.int64(0), n) / (n - 1))


@njit(cache=True, nogil=True)
def pairwise_sum(a, start, n):
    """:func:`_pairwise_sum` from Python (the tests' view)."""
    return _pairwise_sum(a, start, n)


#: candidates evaluated side by side (the lanes of the inner loops): each run's features are read once per this
#: many candidates, not once per candidate, and each step's arithmetic runs over the lanes as one vector loop
_LANES = 16
#: time points of one run whose statistic is produced, then consumed (a (_SEGMENT, _LANES) scratch that stays in
#: the first-level cache), before the next
_SEGMENT = 64
#: a block's lanes in use: its candidates rounded up to a multiple of this (the lanes beyond them compute zeros,
#: never read). Each lane loop runs min(width, _LANES) trips: a count the compiler knows to be short, so it
#: vectorises the loop without interleaving copies of it (with a count it knew nothing of, it would: its vector
#: body would take 16 lanes at once, and a block of 8 would run in scalar code); this is an AVX2 vector of
#: float64. Measured (2 cores, AVX2, the main command's and the 20x workload), a block of 4 candidates costs
#: 0.4-0.6 of a full block, of 6-8 0.6-0.75: not less, as each time step's recursion then waits on its latency
#: (fewer independent lanes do not finish sooner). FusedChartEvaluation.lanes tells callers this number
_VECTOR = 4
#: the fields of the lanes' state, each _LANES values (field f of lane l at [f * _LANES + l]): one array indexed
#: with constant strides, so the compiler sees that no two fields overlap (their distance is at least _LANES,
#: a loop's most trips) and vectorises the lane loops without checking at run time whether they do
_GAIN, _F1, _F2, _CENTER, _LIMIT, _U1, _U2, _V1, _V2, _ALARMS, _MISSES, _ACC = range(12)
_STACK = _ACC + 9  # the pairwise sums' eight accumulators and NumPy's res, then the stack of finished sums
_FIELDS = _STACK + 64


@_helper
def _pairwise_leaves(n):
    """The shape of NumPy's pairwise summation of n values (:func:`_pairwise_sum`), for summing them as they come.

    Returns ``sizes`` (the blocks of at most 128 values that are summed on their own, in order) and ``joins``
    (after each block, how many times the two topmost partial sums are added: left + right): NumPy's recursion,
    run on an explicit stack, recording what it does instead of summing (:func:`_pairwise_sum` replays it).
    """
    # a block (a leaf of the recursion) of a split has at least 64 values, so n // 64 + 1 bound their number
    sizes = np.zeros(n // 64 + 1, np.int64)
    joins = np.zeros(n // 64 + 1, np.int64)
    starts = np.empty(128, np.int64)
    lengths = np.empty(128, np.int64)
    combine = np.zeros(128, np.bool_)
    top = 1
    starts[0], lengths[0], combine[0] = 0, n, False
    n_leaves = 0
    while top > 0:
        top -= 1
        s, m, joining = starts[top], lengths[top], combine[top]
        if joining:
            joins[n_leaves - 1] += 1
        elif m <= _BLOCK:
            sizes[n_leaves] = m
            n_leaves += 1
        else:
            half = m // 2
            half -= half % 8
            starts[top], lengths[top], combine[top] = s, m, True
            starts[top + 1], lengths[top + 1], combine[top + 1] = s + half, m - half, False
            starts[top + 2], lengths[top + 2], combine[top + 2] = s, half, False
            top += 3
    return sizes[:n_leaves], joins[:n_leaves]


@_helper
def _statistics(u_run, v_run, k0, k1, order, combine_max, lanes, width, out, count, faulty, r):
    """Points k0..k1−1 of one run's smoothed-and-combined statistic for the lanes' candidates, side by side.

    u_run, v_run: the run's U_k and V_k (K,); ``lanes``: the lanes' coefficients and the recursion's two past
    values of both parts, carried from the previous call (from k0 = 0, the run's start, a zero state), of
    which the first ``width`` lanes are computed (:data:`_VECTOR`).
    Each value is :func:`mosd.kernels.ewma.ewma_step`'s and each statistic
    :func:`mosd.kernels.ewma.combine_step`'s (max(|U|, |V|) or U² + V²): the chart's step, the one its scan
    (:meth:`mosd.detectors.chart.Chart.scan`) runs. The statistic goes to out[k − k0, lane], or with ``count``
    is scored at once as training run ``r`` of ``faulty``: a healthy point above a lane's limit adds to its
    field ALARMS, a target-fault point not above it to MISSES (from k0 = 0, zeros; counted in floats, exact
    far beyond any run's length, and as arithmetic, so that the lane loop stays one vector loop).
    """
    g, f1, f2 = _GAIN * _LANES, _F1 * _LANES, _F2 * _LANES
    u1, u2, v1, v2 = _U1 * _LANES, _U2 * _LANES, _V1 * _LANES, _V2 * _LANES
    limit, alarms, misses = _LIMIT * _LANES, _ALARMS * _LANES, _MISSES * _LANES
    combine = COMBINE_MAX if combine_max else COMBINE_SS
    if k0 == 0:
        for lane in range(width):
            lanes[u1 + lane] = 0.0
            lanes[u2 + lane] = 0.0
            lanes[v1 + lane] = 0.0
            lanes[v2 + lane] = 0.0
            lanes[alarms + lane] = 0.0
            lanes[misses + lane] = 0.0
    for k in range(k0, k1):
        x, w, i = u_run[k], v_run[k], k - k0
        target = 1.0 * faulty[r, k] if count else 0.0  # 1.0 at a target-fault point
        healthy = 1.0 - target
        for lane in range(min(width, _LANES)):
            a = ewma_step(x, lanes[g + lane], lanes[f1 + lane], lanes[f2 + lane], lanes[u1 + lane], lanes[u2 + lane],
                          order)
            b = ewma_step(w, lanes[g + lane], lanes[f1 + lane], lanes[f2 + lane], lanes[v1 + lane], lanes[v2 + lane],
                          order)
            # whatever the order (order 1 never reads them): a store under a condition is a masked vector store,
            # which the next step's load of the same lanes cannot take from the store buffer, and waits on
            lanes[u2 + lane] = lanes[u1 + lane]
            lanes[v2 + lane] = lanes[v1 + lane]
            lanes[u1 + lane] = a
            lanes[v1 + lane] = b
            s = combine_step(a, b, combine)
            if count:
                alarm = 1.0 * (s > lanes[limit + lane])
                lanes[alarms + lane] += alarm * healthy
                lanes[misses + lane] += (1.0 - alarm) * target
            else:
                out[i, lane] = s


@_helper
def _push_block(lanes, width, res, depth, joins):
    """A finished block's sum (field ``res``) onto each lane's stack of partial sums (fields from STACK, ``depth``
    deep), then the ``joins`` additions of the two top entries that follow that block in NumPy's recursion
    (:func:`_pairwise_leaves`); returns the new depth. Once per block, not per value."""
    top = (_STACK + depth) * _LANES
    for lane in range(width):
        lanes[top + lane] = lanes[res + lane]
    depth += 1
    for _ in range(joins):
        depth -= 1
        left, right = (_STACK + depth - 1) * _LANES, (_STACK + depth) * _LANES
        for lane in range(width):
            lanes[left + lane] = lanes[left + lane] + lanes[right + lane]
    return depth


@_helper
def _accumulate(points, n_points, deviations, lanes, width, cursor, sizes, joins):
    """Add the next ``n_points`` rows of ``points`` (n, lanes) to each lane's pairwise sum, NumPy's, as they come.

    The values of a lane arrive in the order of the flat array NumPy would sum (calibration run by run, each
    in time order); with ``deviations`` a lane adds (x − centre)² instead of x (``np.std``'s terms). The sum
    is :func:`_pairwise_sum`'s, bit for bit, without the array: the blocks and their joins are
    :func:`_pairwise_leaves`'; in a block of eight or more values the lanes' fields ACC + 0..7 are NumPy's
    eight accumulators (each starts at its first value), then ACC + 8 takes their sum and the rest, as
    NumPy's ``res``; a shorter block sums into ACC + 8 from 0.0. The fields from STACK on hold the finished
    partial sums; ``cursor`` (block, position in it, stack depth) carries the place between calls: zeros
    start a sum. After the last value, field STACK is each lane's sum.
    """
    # the lanes' count known only at run time (with the constant _LANES the compiler would unroll these short
    # loops first, then fail to pack the copies into vectors: points and lanes might overlap, as far as it knows),
    # but at most _LANES, so that each loop is one vector loop of a vector's lanes per trip (_VECTOR)
    width = min(width, _LANES)
    block, j, depth = cursor[0], cursor[1], cursor[2]
    if block == sizes.shape[0]:
        return
    center, res = _CENTER * _LANES, (_ACC + 8) * _LANES
    m = sizes[block]
    stop = m - m % 8 if m >= 8 else 0  # where the eight accumulators end (none in a short block)
    if j == 0:
        for lane in range(width):
            lanes[res + lane] = 0.0
    a = _ACC * _LANES
    i = 0
    while i < n_points:
        if j >= 8 and j % 8 == 0 and j + 8 <= stop and i + 8 <= n_points:
            # eight values at once, one to each accumulator, as NumPy's loop adds them: the same sums, with the
            # lane loop's start-up (and its overlap check) paid once per eight values, not per value
            if deviations:
                for lane in range(width):
                    c = lanes[center + lane]
                    d0, d1 = points[i, lane] - c, points[i + 1, lane] - c
                    d2, d3 = points[i + 2, lane] - c, points[i + 3, lane] - c
                    d4, d5 = points[i + 4, lane] - c, points[i + 5, lane] - c
                    d6, d7 = points[i + 6, lane] - c, points[i + 7, lane] - c
                    lanes[a + lane] += d0 * d0
                    lanes[a + _LANES + lane] += d1 * d1
                    lanes[a + 2 * _LANES + lane] += d2 * d2
                    lanes[a + 3 * _LANES + lane] += d3 * d3
                    lanes[a + 4 * _LANES + lane] += d4 * d4
                    lanes[a + 5 * _LANES + lane] += d5 * d5
                    lanes[a + 6 * _LANES + lane] += d6 * d6
                    lanes[a + 7 * _LANES + lane] += d7 * d7
            else:
                for lane in range(width):
                    lanes[a + lane] += points[i, lane]
                    lanes[a + _LANES + lane] += points[i + 1, lane]
                    lanes[a + 2 * _LANES + lane] += points[i + 2, lane]
                    lanes[a + 3 * _LANES + lane] += points[i + 3, lane]
                    lanes[a + 4 * _LANES + lane] += points[i + 4, lane]
                    lanes[a + 5 * _LANES + lane] += points[i + 5, lane]
                    lanes[a + 6 * _LANES + lane] += points[i + 6, lane]
                    lanes[a + 7 * _LANES + lane] += points[i + 7, lane]
            i += 8
            j += 8
        else:
            slot = (_ACC + (j % 8 if j < stop else 8)) * _LANES
            if j < 8 and stop > 0:  # an accumulator's first value: set, as NumPy does (not 0.0 + x: −0.0 stays)
                if deviations:
                    for lane in range(width):
                        d = points[i, lane] - lanes[center + lane]
                        lanes[slot + lane] = d * d
                else:
                    for lane in range(width):
                        lanes[slot + lane] = points[i, lane]
            elif deviations:
                for lane in range(width):
                    d = points[i, lane] - lanes[center + lane]
                    lanes[slot + lane] += d * d
            else:
                for lane in range(width):
                    lanes[slot + lane] += points[i, lane]
            i += 1
            j += 1
        if j == stop:
            for lane in range(width):
                lanes[res + lane] = (((lanes[a + lane] + lanes[a + _LANES + lane])
                                      + (lanes[a + 2 * _LANES + lane] + lanes[a + 3 * _LANES + lane]))
                                     + ((lanes[a + 4 * _LANES + lane] + lanes[a + 5 * _LANES + lane])
                                        + (lanes[a + 6 * _LANES + lane] + lanes[a + 7 * _LANES + lane])))
        if j == m:  # the block is summed: onto the stack, then the joins that follow it in NumPy's recursion
            depth = _push_block(lanes, width, res, depth, joins[block])
            block += 1
            j = 0
            if block == sizes.shape[0]:
                break
            m = sizes[block]
            stop = m - m % 8 if m >= 8 else 0
            for lane in range(width):
                lanes[res + lane] = 0.0
    cursor[0], cursor[1], cursor[2] = block, j, depth


@_helper
def _count(points, n_points, truth, k0, lanes, width):
    """Add points k0.. of one training run (rows of ``points``, (n, lanes)) to each lane's counts: healthy
    points above the lane's limit to field ALARMS, target-fault points not above it to field MISSES (from
    k0 = 0, the run's start, zeroed first; counted in floats, exact far beyond any run's length). Lane by
    lane, each lane's counts in registers: stored per point, they would be reloaded after every store (the
    compiler cannot tell that ``points`` and ``lanes`` never overlap)."""
    limit, alarms, misses = _LIMIT * _LANES, _ALARMS * _LANES, _MISSES * _LANES
    for lane in range(width):
        bound = lanes[limit + lane]
        healthy_alarms = 0.0 if k0 == 0 else lanes[alarms + lane]
        faulty_misses = 0.0 if k0 == 0 else lanes[misses + lane]
        for i in range(n_points):
            alarm = points[i, lane] > bound
            if truth[k0 + i]:
                faulty_misses += not alarm
            else:
                healthy_alarms += alarm
        lanes[alarms + lane] = healthy_alarms
        lanes[misses + lane] = faulty_misses


@_helper
def _buffers(u, feedback, n_calibration, n_points):
    """Both kernels' outputs (zeroed counts (P, R_train)) and scratch: the lanes' state (fields × lanes), the
    pairwise sums' cursor and the statistic of ``n_points`` points (n_points, lanes)."""
    n_columns = u.shape[0]
    n_candidates = feedback.shape[0]
    n_train = n_columns - n_calibration
    return (np.zeros((n_candidates, n_train), np.int64), np.zeros((n_candidates, n_train), np.int64),
            np.zeros(_FIELDS * _LANES), np.zeros(3, np.int64), np.empty((n_points, _LANES)))


@_helper
def _lanes(gains, feedback, widths, p0, lanes):
    """Candidates p0.. into the lanes: their gains, f1, f2 (0 for order 1) and, in field LIMIT, their widths
    K, which the Phase-I limit replaces once it is known. Lanes past the last candidate get zeros (a zero
    statistic, computed and never read). Returns the number of candidates placed."""
    order = feedback.shape[1]
    n_lanes = min(_LANES, feedback.shape[0] - p0)
    for lane in range(_LANES):
        p = p0 + lane
        real = lane < n_lanes
        lanes[_GAIN * _LANES + lane] = gains[p] if real else 0.0
        lanes[_F1 * _LANES + lane] = feedback[p, 0] if real else 0.0
        lanes[_F2 * _LANES + lane] = feedback[p, 1] if real and order == 2 else 0.0
        lanes[_LIMIT * _LANES + lane] = widths[p] if real else 0.0
    return n_lanes


@_helper
def _limits(lanes, n_values, deviations):
    """After the pairwise sum of every calibration point: the lanes' centre E{l} (``deviations`` False), or
    their Phase-I limit E{l} + K·sd{l} (True), as ``mean_std`` and ``Chart.fit_statistic`` compute them."""
    for lane in range(_LANES):
        total = lanes[_STACK * _LANES + lane]
        if deviations:
            center = lanes[_CENTER * _LANES + lane]
            lanes[_LIMIT * _LANES + lane] = center + lanes[_LIMIT * _LANES + lane] * math.sqrt(total / (n_values - 1))
        else:
            lanes[_CENTER * _LANES + lane] = total / n_values


@njit(cache=True, nogil=True)
def alarm_counts(u, v, n_calibration, gains, feedback, widths, combine_max, faulty):
    """Per-run alarm counts of every candidate, fused (module docstring), with no denoiser.

    Parameters
    ----------
    u, v : float64 (C, K), run-major
        U_k and V_k of the calibration runs (first ``n_calibration`` rows) then the training runs.
    gains : (P,); feedback : (P, order); widths : (P,)
        Each candidate's recursion coefficients (as ``ewma_time_major`` computes them) and its K.
    faulty : bool (R_train, K)
        Target-fault truth of the training runs.

    Returns
    -------
    healthy_alarms, faulty_misses : int64 (P, R_train)

    Candidates go through in blocks of :data:`_LANES` (the last one's lanes rounded up to :data:`_VECTOR`
    candidates: a short slice costs its lanes, not a full block's), each run's points in segments of :data:`_SEGMENT`;
    no statistic is kept beyond a segment: the Phase-I limit's mean and deviations are summed as the
    calibration points are produced (the recursion runs twice over the calibration runs, which is cheaper
    than writing and reading them back), then each training point is scored as it is produced.

    A kernel of its own (not a flag of :func:`alarm_counts_denoised`): numba compiles every function a
    body calls, taken branch or not, so a run without a denoiser never compiles the wavelet.
    """
    n_columns, n_points = u.shape
    order = feedback.shape[1]
    # int64 arguments, as the denoised kernel's: a literal (the constant _SEGMENT, a 0) would compile a helper again
    healthy_alarms, faulty_misses, lanes, cursor, points = _buffers(u, feedback, n_calibration, np.int64(_SEGMENT))
    scored = np.bool_(False)
    n_values = n_calibration * n_points
    sizes, joins = _pairwise_leaves(n_values)
    for p0 in range(0, feedback.shape[0], _LANES):
        n_lanes = _lanes(gains, feedback, widths, p0, lanes)
        width = (n_lanes + _VECTOR - 1) // _VECTOR * _VECTOR
        # the Phase-I limit E{l} + K·sd{l} (Chart.fit_statistic): the mean, then the squared deviations from it
        for deviations in range(2):
            cursor[0], cursor[1], cursor[2] = 0, 0, 0
            for c in range(n_calibration):
                for k0 in range(0, n_points, _SEGMENT):
                    k1 = min(n_points, k0 + _SEGMENT)
                    _statistics(u[c], v[c], k0, k1, order, combine_max, lanes, width, points, scored, faulty, c)
                    _accumulate(points, k1 - k0, deviations == 1, lanes, width, cursor, sizes, joins)
            _limits(lanes, n_values, deviations == 1)
        for r in range(n_columns - n_calibration):
            for k0 in range(0, n_points, _SEGMENT):
                k1 = min(n_points, k0 + _SEGMENT)
                _statistics(u[n_calibration + r], v[n_calibration + r], k0, k1, order, combine_max, lanes, width,
                            points, not scored, faulty, r)
            for lane in range(n_lanes):
                healthy_alarms[p0 + lane, r] = lanes[_ALARMS * _LANES + lane]
                faulty_misses[p0 + lane, r] = lanes[_MISSES * _LANES + lane]
    return healthy_alarms, faulty_misses


@njit(cache=True, nogil=True)
def alarm_counts_denoised(u, v, n_calibration, gains, feedback, widths, combine_max, faulty,
                          lo, hi, rec_lo, rec_hi, level, per_level, source, rule, fixed, hard):
    """:func:`alarm_counts` with each run's statistic wavelet-denoised before the limit and the counts
    (the remaining arguments: :func:`mosd.kernels.wavelet.denoise_row`).

    The denoiser needs a run's whole statistic, so each run's is produced whole for the block's lanes; the
    denoised calibration points are kept (the limit's second pass reads them again: denoising them twice
    would cost more than keeping them) and summed as :func:`alarm_counts` sums them.
    """
    n_columns, n_points = u.shape
    order = feedback.shape[1]
    healthy_alarms, faulty_misses, lanes, cursor, raw = _buffers(u, feedback, n_calibration, n_points)
    # of types int64 and bool, as alarm_counts' segment starts and flag (literals would compile the helpers again)
    start, scored = np.int64(0), np.bool_(False)
    n_values = n_calibration * n_points
    sizes, joins = _pairwise_leaves(n_values)
    kept = np.zeros((n_calibration, n_points, _LANES))  # zeros in the unused lanes of a last, partial block
    plotted = np.zeros((n_points, _LANES))
    row = np.empty(n_points)
    denoised = np.empty(n_points)
    work = np.empty(work_size(n_points, lo.shape[0], level))
    for p0 in range(0, feedback.shape[0], _LANES):
        n_lanes = _lanes(gains, feedback, widths, p0, lanes)
        width = (n_lanes + _VECTOR - 1) // _VECTOR * _VECTOR
        for c in range(n_columns):
            _statistics(u[c], v[c], start, n_points, order, combine_max, lanes, width, raw, scored, faulty, c)
            target = kept[c] if c < n_calibration else plotted
            for lane in range(n_lanes):
                for k in range(n_points):
                    row[k] = raw[k, lane]
                denoise_row(row, denoised, work, lo, hi, rec_lo, rec_hi, level, per_level, source, rule, fixed, hard)
                for k in range(n_points):
                    target[k, lane] = denoised[k]
            if c == n_calibration - 1:  # every calibration point is in: the Phase-I limit, as alarm_counts
                for deviations in range(2):
                    cursor[0], cursor[1], cursor[2] = 0, 0, 0
                    for cal in range(n_calibration):
                        _accumulate(kept[cal], n_points, deviations == 1, lanes, width, cursor, sizes, joins)
                    _limits(lanes, n_values, deviations == 1)
            elif c >= n_calibration:
                r = c - n_calibration
                _count(plotted, n_points, faulty[r], start, lanes, width)
                for lane in range(n_lanes):
                    healthy_alarms[p0 + lane, r] = lanes[_ALARMS * _LANES + lane]
                    faulty_misses[p0 + lane, r] = lanes[_MISSES * _LANES + lane]
    return healthy_alarms, faulty_misses


def _warm_up_arguments():
    u = np.zeros((3, 64))  # run-major: 1 calibration run, 2 training runs of 64 points
    faulty = np.zeros((2, 64), bool)
    # every array contiguous, as FusedChartEvaluation.plan makes them (a slice of its rows stays contiguous): a
    # strided one here would compile a signature the run never calls, and the run would compile its own
    return (u, u, 1, np.ones(2), np.zeros((2, 2)), np.ones(2), False, faulty)


def warm_up(denoised: bool = False) -> None:
    """Load (or compile) the kernel without a denoiser, and with ``denoised`` also the wavelet one
    (:func:`warm_up_denoised`)."""
    alarm_counts(*_warm_up_arguments())
    if denoised:
        warm_up_denoised()


def warm_up_denoised() -> None:
    """Load (or compile) the kernel with the wavelet denoiser (db3, three levels, SURE: the paper's wavelet)."""
    import pywt

    from .wavelet import RULE_SURE, SOURCE_COARSEST

    wavelet = pywt.Wavelet("db3")
    filters = [np.asarray(f, float) for f in (wavelet.dec_lo, wavelet.dec_hi, wavelet.rec_lo, wavelet.rec_hi)]
    args = (*filters, 3, False, SOURCE_COARSEST, RULE_SURE, np.zeros(3), False)
    alarm_counts_denoised(*_warm_up_arguments(), *args)


def warm_up_all() -> None:
    """Both kernels (``python -m mosd.kernels``)."""
    warm_up(denoised=True)

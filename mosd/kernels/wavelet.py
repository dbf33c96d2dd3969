"""Whole-series wavelet denoising of :class:`mosd.denoisers.WaveletDenoiser`, compiled and batched.

Each sequence is processed on its own with scalar loops (the sums of one
output are a short dependency chain; consecutive outputs overlap in the CPU),
every sum formed in exactly the order of PyWavelets' C code (``downsampling_convolution``
and ``upsampling_convolution_valid_sf`` in symmetric mode) and of MATLAB's
rules as :mod:`mosd.denoisers.wavelet` implements them. The results are
therefore bit-identical to the reference, not merely close.

Supported (:func:`supports`): noise scaling ``'one'`` (the paper's literal call),
threshold rules ``rigrsure``, ``sqtwolog``, ``minimaxi``, global or per-level
thresholds, soft or hard shrinkage, even-length filters, and series long enough
that every level's input is at least one filter long. Anything else runs on the
reference path.

When the threshold removes every detail — the paper's literal setting on an
in-control statistic — the reconstruction is the approximation-only one, a
fixed linear low-pass of the input: the detail branch of the inverse transform
is skipped, which changes no bit (it would add exact zeros).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile

RULE_SURE, RULE_FIXED = 0, 1
SOURCE_COARSEST, SOURCE_FINEST, SOURCE_ALL = 0, 1, 2


@njit(cache=True, nogil=True)
def _dwt_symmetric(x, n, lo, hi, ca, cd, even, odd):
    """One DWT level of x[:n] (n >= len(lo)) into ca, cd, each (n + F − 1)//2 long.

    PyWavelets' loops: the left overhang (i < F) adds the direct taps j = 0..i then
    the mirrored ones; the centre adds j = 0..F−1; the right overhang adds the
    mirrored taps first, filter index descending, then the direct ones. The centre
    runs tap by tap over all its outputs (each output still sums its taps in
    order j = 0, 1, ...) on the even and odd samples (``even``, ``odd``: scratch),
    so that the compiler vectorises it.
    """
    n_taps = lo.shape[0]
    n_out = (n + n_taps - 1) // 2
    o_centre, o_right = n_taps // 2, n // 2
    # left overhang: i = 2o + 1 < F
    for o in range(o_centre):
        i = 2 * o + 1
        a = 0.0
        d = 0.0
        for j in range(i + 1):
            v = x[i - j]
            a += lo[j] * v
            d += hi[j] * v
        for j in range(i + 1, n_taps):
            v = x[j - i - 1]
            a += lo[j] * v
            d += hi[j] * v
        ca[o] = a
        cd[o] = d
    # centre: F <= i < n; x[2o + 1 − j] is odd[o − j/2] for even j, even[o − (j−1)/2] for odd j
    m = o_right - o_centre
    if m > 0:
        for k in range((n + 1) // 2):
            even[k] = x[2 * k]
        for k in range(n // 2):
            odd[k] = x[2 * k + 1]
        a_out = ca[o_centre:o_right]
        d_out = cd[o_centre:o_right]
        for t in range(m):
            a_out[t] = 0.0
            d_out[t] = 0.0
        for j in range(n_taps):
            fl, fh, q = lo[j], hi[j], j // 2
            src = odd[o_centre - q:o_right - q] if j % 2 == 0 else even[o_centre - q:o_right - q]
            for t in range(m):
                v = src[t]
                a_out[t] += v * fl
                d_out[t] += v * fh
    # right overhang: i >= n
    for o in range(o_right, n_out):
        i = 2 * o + 1
        a = 0.0
        d = 0.0
        for j in range(i - n + 1):
            v = x[n - 1 - j]
            a += lo[i - n - j] * v
            d += hi[i - n - j] * v
        for j in range(i - n + 1, n_taps):
            v = x[i - j]
            a += lo[j] * v
            d += hi[j] * v
        ca[o] = a
        cd[o] = d


@njit(cache=True, nogil=True)
def _upsample(coefficients, n, rec, even, odd):
    """even[t], odd[t] = Σ_j rec[2j]·c[t + F/2 − 1 − j], Σ_j rec[2j+1]·c[...], j ascending, t < n − F/2 + 1."""
    half = rec.shape[0] // 2
    m = n - half + 1
    e = even[:m]
    d = odd[:m]
    for t in range(m):
        e[t] = 0.0
        d[t] = 0.0
    for j in range(half):
        fe, fo = rec[2 * j], rec[2 * j + 1]
        src = coefficients[half - 1 - j:half - 1 - j + m]
        for t in range(m):
            v = src[t]
            e[t] += fe * v
            d[t] += fo * v


@njit(cache=True, nogil=True)
def _idwt(approx, details, n, rec_lo, rec_hi, with_details, out, even, odd, even_d, odd_d):
    """out[:2n − F + 2] = the 'valid' upsampling convolutions of approx[:n] (rec_lo) and details[:n] (rec_hi).

    As PyWavelets' idwt: each output starts at zero, gets the approximation's
    even or odd sum, then the details' (skipped when they are all zero, which
    would add exact zeros).
    """
    m = n - rec_lo.shape[0] // 2 + 1
    _upsample(approx, n, rec_lo, even, odd)
    if with_details:
        _upsample(details, n, rec_hi, even_d, odd_d)
        for t in range(m):
            out[2 * t] = (0.0 + even[t]) + even_d[t]
            out[2 * t + 1] = (0.0 + odd[t]) + odd_d[t]
    else:
        for t in range(m):
            out[2 * t] = 0.0 + even[t]
            out[2 * t + 1] = 0.0 + odd[t]


@njit(cache=True, nogil=True)
def _sort_squares(a, n):
    """Ascending sort of a[:n] in place, for squares (non-negative, no NaN): LSD radix on the bit patterns.

    Non-negative doubles order as their unsigned 64-bit patterns, and a sorted
    array is the same whatever sorts it, so this changes no bit of the
    threshold; it takes ~1.7 µs for the 129 coarsest coefficients against
    ~4.1 µs for ``np.sort`` (a comparison sort's unpredictable branches).
    A pass whose digit all keys share is skipped.
    """
    keys = np.empty(n, np.uint64)
    spare = np.empty(n, np.uint64)
    counts = np.empty(256, np.int64)
    bits = a[:n].view(np.uint64)
    for i in range(n):
        keys[i] = bits[i]
    source, target = keys, spare
    for shift in range(0, 64, 8):
        digit_shift = np.uint64(shift)
        for d in range(256):
            counts[d] = 0
        for i in range(n):
            counts[(source[i] >> digit_shift) & np.uint64(255)] += 1
        if counts[(source[0] >> digit_shift) & np.uint64(255)] == n:
            continue
        total = 0
        for d in range(256):
            c = counts[d]
            counts[d] = total
            total += c
        for i in range(n):
            d = (source[i] >> digit_shift) & np.uint64(255)
            target[counts[d]] = source[i]
            counts[d] += 1
        source, target = target, source
    ordered = source.view(np.float64)
    for i in range(n):
        a[i] = ordered[i]


@njit(cache=True, nogil=True)
def _sure(values, m, squares):
    """MATLAB's rigrsure threshold of values[:m] (mosd.denoisers.wavelet._sure_threshold); squares: scratch."""
    largest = 0.0
    for i in range(m):
        s = values[i] * values[i]
        squares[i] = s
        if s > largest:
            largest = s
    if largest < 2.0:
        return math.sqrt(largest)
    _sort_squares(squares, m)
    ordered = squares
    best = 0
    best_risk = np.inf
    total = 0.0
    for i in range(m):
        total += ordered[i]
        index = float(i + 1)
        risk = total + (m - index) * ordered[i]
        risk -= 2.0 * index
        if risk < best_risk:
            best_risk = risk
            best = i
    return math.sqrt(ordered[best])


@njit(cache=True, nogil=True)
def _shrink(values, start, stop, t, hard):
    """wthresh in place on values[start:stop]; True when anything survives."""
    any_kept = False
    for i in range(start, stop):
        v = values[i]
        if hard:
            r = v if abs(v) > t else 0.0
        elif v > t:
            r = v - t
        elif v < -t:
            r = v + t
        else:
            r = 0.0
        values[i] = r
        if r != 0.0:
            any_kept = True
    return any_kept


@njit(cache=True, nogil=True)
def denoise_row(x, out, work, lo, hi, rec_lo, rec_hi, level, per_level, source, rule, fixed, hard):
    """Wavelet-threshold denoising of one sequence x (n,) into out (n,); work: scratch of :func:`work_size`.

    Parameters
    ----------
    per_level : bool
        One threshold per level (``scope='level'``) instead of one global threshold.
    source : int
        SOURCE_COARSEST / SOURCE_FINEST / SOURCE_ALL: the details a global threshold is selected from.
    rule : int
        RULE_SURE (rigrsure) or RULE_FIXED (a threshold that depends on the count only, in ``fixed``).
    fixed : float64 (level,)
        The fixed threshold of each level, finest first (per-level scope), or fixed[0] (global).
    hard : bool
        Hard instead of soft shrinkage.
    """
    n = x.shape[0]
    n_taps = lo.shape[0]
    # work: details of every level (finest first), squares for rigrsure, four half-length and two full-length buffers
    lengths = np.empty(level + 1, np.int64)
    lengths[0] = n
    offsets = np.zeros(level + 1, np.int64)
    for lev in range(1, level + 1):
        lengths[lev] = (lengths[lev - 1] + n_taps - 1) // 2
        offsets[lev] = offsets[lev - 1] + lengths[lev]
    n_details = offsets[level]
    span = n // 2 + n_taps + 2
    details = work[:n_details]
    squares = work[n_details:2 * n_details]
    base = 2 * n_details
    even = work[base:base + span]
    odd = work[base + span:base + 2 * span]
    even_d = work[base + 2 * span:base + 3 * span]
    odd_d = work[base + 3 * span:base + 4 * span]
    full = n + n_taps + 2  # an approximation, or a reconstruction (at most n + 1 long)
    buffers = work[base + 4 * span:base + 4 * span + 2 * full].reshape((2, full))
    which = 0
    _dwt_symmetric(x, n, lo, hi, buffers[0], details[:offsets[1]], even, odd)
    for lev in range(2, level + 1):
        _dwt_symmetric(buffers[which], lengths[lev - 1], lo, hi, buffers[1 - which],
                       details[offsets[lev - 1]:offsets[lev]], even, odd)
        which = 1 - which
    kept = np.zeros(level + 1, np.bool_)
    if per_level:
        for lev in range(1, level + 1):
            start, stop = offsets[lev - 1], offsets[lev]
            t = _sure(details[start:stop], stop - start, squares) if rule == RULE_SURE else fixed[lev - 1]
            kept[lev] = _shrink(details, start, stop, t, hard)
    else:
        if rule == RULE_SURE:
            if source == SOURCE_COARSEST:
                start, stop = offsets[level - 1], offsets[level]
            elif source == SOURCE_FINEST:
                start, stop = 0, offsets[1]
            else:
                start, stop = 0, offsets[level]
            t = _sure(details[start:stop], stop - start, squares)
        else:
            t = fixed[0]
        for lev in range(1, level + 1):
            kept[lev] = _shrink(details, offsets[lev - 1], offsets[lev], t, hard)
    # reconstruction, coarsest first; an approximation one longer than the details is trimmed (pywt.waverec)
    a_len = lengths[level]
    direct = False
    for lev in range(level, 0, -1):
        d_len = lengths[lev]
        if a_len == d_len + 1:
            a_len = d_len
        out_len = 2 * a_len - n_taps + 2
        direct = lev == 1 and out_len == n  # the last step can write straight into out
        target = out if direct else buffers[1 - which]
        _idwt(buffers[which], details[offsets[lev - 1]:offsets[lev]], a_len, rec_lo, rec_hi, kept[lev], target, even,
              odd, even_d, odd_d)
        which = 1 - which
        a_len = out_len
    if not direct:
        source = buffers[which]
        for k in range(n):
            out[k] = source[k]


@njit(cache=True, nogil=True)
def work_size(n, n_taps, level):
    """Scratch length :func:`denoise_row` needs for a sequence of n."""
    length = n
    total = 0
    for _ in range(level):
        length = (length + n_taps - 1) // 2
        total += length
    return 2 * total + 4 * (n // 2 + n_taps + 2) + 2 * (n + n_taps + 2)


@njit(cache=True, nogil=True)
def denoise_rows(x, lo, hi, rec_lo, rec_hi, level, per_level, source, rule, fixed, hard):
    """:func:`denoise_row` on every row of x (B, n)."""
    rows, n = x.shape
    out = np.empty((rows, n))
    work = np.empty(work_size(n, lo.shape[0], level))
    for r in range(rows):
        denoise_row(x[r], out[r], work, lo, hi, rec_lo, rec_hi, level, per_level, source, rule, fixed, hard)
    return out


class Plan:
    """The constant arguments of :func:`denoise_columns` for one denoiser (None when unsupported)."""

    def __init__(self, denoiser):
        import pywt

        # the count-only rules are the denoiser's own (mosd.denoisers.wavelet.count_threshold): passed
        # in, not imported, so that the kernel does not import its component
        self.count_threshold = denoiser.count_threshold

        wavelet = pywt.Wavelet(denoiser.wavelet)
        self.lo = np.asarray(wavelet.dec_lo, float)
        self.hi = np.asarray(wavelet.dec_hi, float)
        self.rec_lo = np.asarray(wavelet.rec_lo, float)
        self.rec_hi = np.asarray(wavelet.rec_hi, float)
        self.level = int(denoiser.level)
        self.per_level = denoiser.scope == "level"
        self.source = {"coarsest": SOURCE_COARSEST, "finest": SOURCE_FINEST, "all": SOURCE_ALL}[denoiser.global_source]
        self.rule = RULE_SURE if denoiser.threshold == "rigrsure" else RULE_FIXED
        self.threshold = denoiser.threshold
        self.hard = denoiser.mode == "hard"

    def lengths(self, n: int) -> list[int]:
        """Input length of every level, then the coarsest output length."""
        lengths = [n]
        for _ in range(self.level):
            lengths.append((lengths[-1] + self.lo.size - 1) // 2)
        return lengths

    def fits(self, n: int) -> bool:
        """True when every level's input is at least one filter long (the only case compiled)."""
        return all(length >= self.lo.size for length in self.lengths(n)[:-1])

    def fixed(self, n: int) -> np.ndarray:
        """The count-only thresholds (sqtwolog, minimaxi) exactly as the denoiser's ``select_threshold`` computes them."""
        lengths = self.lengths(n)[1:]  # finest first
        if self.rule == RULE_SURE:
            return np.zeros(self.level)
        if self.per_level:
            counts = lengths
        else:
            count = {SOURCE_COARSEST: lengths[-1], SOURCE_FINEST: lengths[0], SOURCE_ALL: sum(lengths)}[self.source]
            counts = [count] * self.level
        return np.array([self.count_threshold(m, self.threshold) for m in counts])

    def arguments(self, n: int) -> tuple:
        """The constant trailing arguments of :func:`denoise_row` for sequences of n."""
        return (self.lo, self.hi, self.rec_lo, self.rec_hi, self.level, self.per_level, self.source, self.rule,
                self.fixed(n), self.hard)

    def __call__(self, rows: np.ndarray) -> np.ndarray:
        """Denoise every row of a (B, n) array."""
        return denoise_rows(np.ascontiguousarray(rows, dtype=float), *self.arguments(rows.shape[-1]))


def plan(denoiser) -> Plan | None:
    """A compiled plan for ``denoiser`` when the kernel reproduces it, else None."""
    if getattr(denoiser, "window", None) is not None or getattr(denoiser, "scaling", None) != "one":
        return None
    if getattr(denoiser, "threshold", None) not in ("rigrsure", "sqtwolog", "minimaxi"):
        return None
    result = Plan(denoiser)
    if result.lo.size % 2 or result.lo.size < 2:
        return None
    return result


def warm_up() -> None:
    """Load (or compile) the kernels: the argument types of every :class:`Plan` (db3, three levels)."""
    import pywt

    wavelet = pywt.Wavelet("db3")
    filters = [np.asarray(f, float) for f in (wavelet.dec_lo, wavelet.dec_hi, wavelet.rec_lo, wavelet.rec_hi)]
    denoise_rows(np.zeros((2, 64)), *filters, 3, False, SOURCE_COARSEST, RULE_SURE, np.zeros(3), False)

"""Wavelet denoising of a chart statistic (paper 000, §3.2; docs/DECISIONS.md §4).

Paper 000 smooths the SS-DEWMA statistic {L_k} (eqs. 19–25) before comparing it
with the limit of eq. 27: MATLAB ``wavedec(L, 3, 'db3')``, a threshold from
``thselect(D, 'rigrsure')`` and ``wdencmp`` reconstruction give {l_k}. This module
reproduces those MATLAB semantics with PyWavelets, vectorised over a batch of
sequences (any leading shape, time along the last axis):

* decomposition: ``pywt.wavedec`` with mode ``'symmetric'`` (MATLAB's default
  ``dwtmode('sym')``); reconstruction is cut back to the input length, which is
  what MATLAB's ``waverec`` does with the bookkeeping vector ``L``;
* threshold rules (:func:`select_threshold`): ``thselect``'s ``'rigrsure'``,
  ``'heursure'``, ``'sqtwolog'`` and ``'minimaxi'``, all derived for unit-variance
  white noise;
* noise rescaling as ``wden``'s ``SCAL`` argument: ``'one'`` (none), ``'sln'``
  (one σ̂ = median|cD₁|/0.6745 from the finest details), ``'mln'`` (one σ̂ per
  level). Rules are applied to coefficients divided by σ̂ and the threshold is
  multiplied back;
* ``wthresh`` soft/hard shrinkage (:func:`threshold_coefficients`); hard
  thresholding zeroes |x| = t as MATLAB does (``pywt.threshold`` keeps it);
* approximation coefficients are never thresholded (``wdencmp`` with keepapp = 1).

Whole-series denoising is non-causal: l_k depends on L_{k+1}, L_{k+2}, ... A
causal sliding-window mode is available (``window=w``); :meth:`describe` says
which one a result used.
"""
from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..validation import Component, Interval, Param, check_choice

if TYPE_CHECKING:
    import pywt

#: Threshold selection rules of MATLAB's ``thselect``.
THRESHOLD_RULES = ("rigrsure", "heursure", "sqtwolog", "minimaxi")
#: Noise rescaling options of MATLAB's ``wden`` (argument SCAL).
SCALINGS = ("one", "sln", "mln")
#: Thresholding functions of MATLAB's ``wthresh``.
THRESHOLD_MODES = ("soft", "hard")
#: One threshold for all detail levels (``wdencmp 'gbl'``) or one per level (``'lvd'``).
SCOPES = ("global", "level")
#: Which detail coefficients a global threshold is selected from.
GLOBAL_SOURCES = ("all", "finest", "coarsest")

# median(|N(0,1)|): turns the median absolute detail into a noise standard deviation
# (Donoho & Johnstone; MATLAB's wnoisest).
_MAD_TO_SIGMA = 0.6745
# Elements of one chunk of sliding windows in causal mode: bounds memory at ~32 MB
# per intermediate array while keeping each PyWavelets call large enough to be cheap.
_CAUSAL_CHUNK_ELEMENTS = 1 << 22


def _discrete_wavelets() -> list[str]:
    """PyWavelets' discrete wavelets; pywt is imported where it is used: a run without this denoiser never loads it."""
    import pywt

    return pywt.wavelist(kind="discrete")


def select_threshold(coefficients, rule: str = "rigrsure") -> np.ndarray:
    """Threshold selected from coefficients assuming unit-variance white noise.

    MATLAB ``thselect(X, rule)`` applied to every row of ``coefficients`` at once.

    Parameters
    ----------
    coefficients : array_like, shape (..., n)
        Coefficients (already divided by the noise σ̂ when rescaling is wanted).
        The rule is applied along the last axis.
    rule : {'rigrsure', 'heursure', 'sqtwolog', 'minimaxi'}
        ``'rigrsure'``: the minimiser of Stein's unbiased risk estimate for soft
        thresholding (see Notes). ``'sqtwolog'``: the universal threshold
        sqrt(2 ln n). ``'heursure'``: sqtwolog when the energy excess
        (Σx² − n)/n is below log2(n)^1.5/√n (too little signal for SURE to be
        reliable), otherwise min(rigrsure, sqtwolog). ``'minimaxi'``: 0 for
        n ≤ 32, otherwise 0.3936 + 0.1829·log2(n).

    Returns
    -------
    ndarray, shape (...)
        One threshold per row.

    Notes
    -----
    For soft thresholding at t of x_j = θ_j + e_j with e_j ~ N(0, 1), Stein's
    unbiased estimate of the risk Σ E(x̂_j − θ_j)² is

        SURE(t) = n − 2·#{j : |x_j| ≤ t} + Σ_j min(x_j², t²).

    Between consecutive sorted |x| values the count is constant and the sum grows
    with t, so the minimum over t ≥ |x|_(1) sits at one of the |x_j|. With
    s_1 ≤ … ≤ s_n the sorted x² and t = √s_i (1-based i), #{|x| ≤ t} = i and
    Σ min(x², t²) = Σ_{j ≤ i} s_j + (n − i)·s_i, so

        risk_i = (n − 2i + cumsum(s)_i + (n − i)·s_i) / n,

    and the threshold is √s_{argmin}. This is MATLAB's rule; like MATLAB it does
    not consider t < |x|_(1) (in particular t = 0). Ties are harmless: at tied
    values the formula over-states the risk except at the last tied index, where
    it is exact, so the minimum is unchanged.
    """
    check_choice("denoise.threshold", rule, THRESHOLD_RULES)
    x = np.asarray(coefficients, dtype=float)
    if x.ndim == 0 or x.shape[-1] == 0:
        raise ValueError("select_threshold needs at least one coefficient along the last axis")
    n = x.shape[-1]
    if rule == "sqtwolog":
        return np.full(x.shape[:-1], math.sqrt(2.0 * math.log(n)))
    if rule == "minimaxi":
        value = 0.0 if n <= 32 else 0.3936 + 0.1829 * math.log2(n)
        return np.full(x.shape[:-1], value)
    sure = _sure_threshold(x)
    if rule == "rigrsure":
        return sure
    universal = math.sqrt(2.0 * math.log(n))
    energy_excess = (np.einsum("...i,...i->...", x, x) - n) / n
    too_little_signal = energy_excess < math.log2(n) ** 1.5 / math.sqrt(n)
    return np.where(too_little_signal, universal, np.minimum(sure, universal))


#: the threshold rules the compiled kernel reproduces (mosd.kernels.wavelet)
_KERNEL_RULES = select_threshold


def count_threshold(n: int, rule: str) -> float:
    """The threshold of a rule that depends on the count only (sqtwolog, minimaxi) for n coefficients.

    The constant the compiled kernel (:mod:`mosd.kernels.wavelet`) is given for such a rule:
    :func:`select_threshold` itself, on n zeros.
    """
    return float(select_threshold(np.zeros((1, n)), rule)[0])


def _sure_threshold(x: np.ndarray) -> np.ndarray:
    """rigrsure along the last axis (see :func:`select_threshold`, Notes)."""
    n = x.shape[-1]
    squares = np.square(x)
    # Exact shortcut: if every x² < 2, n·(risk_i − risk_n) = 2(n−i) + (n−i)x²_(i)
    # − Σ_{j>i} x²_(j) > 0 for all i < n, so the minimiser is the largest |x| and
    # no sort is needed. Rows of a small chart statistic (unit-noise scaling) all
    # take this path.
    largest = squares.max(axis=-1)
    small = largest < 2.0
    if small.all():
        return np.sqrt(largest)
    if small.any():
        out = np.sqrt(largest)
        out[~small] = _sure_threshold(x[~small])
        return out
    squares.sort(axis=-1)
    index = np.arange(1, n + 1, dtype=float)
    # n·risk_i; the constant factor 1/n does not move the argmin.
    risk = np.cumsum(squares, axis=-1)
    risk += (n - index) * squares
    risk -= 2.0 * index
    best = np.argmin(risk, axis=-1)
    return np.sqrt(np.take_along_axis(squares, best[..., None], axis=-1)[..., 0])


def threshold_coefficients(coefficients, threshold, mode: str = "soft") -> np.ndarray:
    """MATLAB ``wthresh``: soft or hard thresholding.

    Parameters
    ----------
    coefficients : array_like
    threshold : array_like
        Broadcast against ``coefficients`` (e.g. shape (..., 1) for one threshold per row).
    mode : {'soft', 'hard'}
        ``'soft'``: sign(x)·max(|x| − t, 0). ``'hard'``: x where |x| > t, else 0 —
        so |x| = t is zeroed, as in MATLAB (``pywt.threshold`` keeps it).

    Returns
    -------
    ndarray
    """
    check_choice("denoise.mode", mode, THRESHOLD_MODES)
    x = np.asarray(coefficients, dtype=float)
    t = np.asarray(threshold, dtype=float)
    if mode == "hard":
        return np.where(np.abs(x) > t, x, 0.0)
    # x − clip(x, −t, t) equals sign(x)·max(|x| − t, 0) in two passes instead of five.
    shrunk = np.clip(x, -t, t)
    np.subtract(x, shrunk, out=shrunk)
    return shrunk


class WaveletDenoiser(Component):
    """Wavelet-threshold denoising of chart statistics (paper 000, §3.2).

    The defaults are the paper's literal setting: ``scaling='one', scope='global',
    global_source='coarsest'``. Measured on the SS-DEWMA statistic (λ = 0.3, in
    control, L ≈ 0.18 ± 0.18): with ``'one'`` no detail survives (l_k is the
    level-3 approximation, a low-pass of L_k), while ``'sln'`` keeps ~64 % of
    the details (corr(l, L) = 0.995) because the finest details of a
    twice-smoothed statistic are tiny — so it is the unscaled rule, not
    ``'sln'``, that "keeps only the approximation" (correcting
    docs/DECISIONS.md §4). Under a fault L is large and details survive the
    unscaled rule too.

    Notes
    -----
    ``min_length = (dec_len − 1)·2**level`` (40 for db3, level 3) is the
    shortest series PyWavelets decomposes to ``level`` without warning that the
    coarsest details are all boundary effect (``pywt.dwt_max_level``).
    """

    #: the count-only threshold rules, as the compiled kernel's plan takes them (:mod:`mosd.kernels.wavelet`)
    count_threshold = staticmethod(count_threshold)

    config_group = "denoise"
    params = {
        "wavelet": Param(lambda key, value, d: check_choice(key, value, _discrete_wavelets()),
                         "A discrete wavelet known to PyWavelets (``pywt.wavelist(kind=\"discrete\")``); paper 000: "
                         "db3.", kind="str"),
        "level": Param(Interval(1, 12, integer=True), "Decomposition depth (paper 000: 3)."),
        "threshold": Param(THRESHOLD_RULES, "Threshold selection rule, see :func:`select_threshold` (paper 000: "
                           "rigrsure)."),
        "mode": Param(THRESHOLD_MODES, "Shrinkage function (``wdencmp``'s SORH), see :func:`threshold_coefficients`."),
        "scaling": Param(SCALINGS, "Noise rescaling (``wden``'s SCAL). The rules assume unit noise; sln divides all "
                         "details by σ̂ = median|cD₁|/0.6745 before selecting and multiplies the threshold back, mln "
                         "does so with one σ̂ per level, one uses the coefficients as they are (the paper's literal "
                         "``thselect`` call). Where σ̂ is negligible (≤ √eps · max|d| of its level, a guard like "
                         "``wden``'s) or zero, that level's threshold is 0 and its details are kept."),
        "scope": Param(SCOPES, "global: one threshold (in units of σ̂) for all detail levels, as "
                       "``wdencmp('gbl', ...)``; level: one threshold per level from that level's coefficients, as "
                       "``wden``/``wdencmp('lvd', ...)``. With scaling=mln a global threshold is one value in units "
                       "of each level's σ̂, so in absolute terms it differs between levels."),
        "global_source": Param(GLOBAL_SOURCES, "Which (σ̂-normalised) details a global threshold is selected from: "
                               "all concatenates every detail level (the SURE it minimises is then the estimated "
                               "risk of exactly the operation applied); coarsest is the paper's literal call (MATLAB "
                               "``detcoef(C, L)`` without a level returns cD_level); finest uses cD₁, where the noise "
                               "dominates. Ignored when scope=level. Rules that depend on n only (sqtwolog, minimaxi) "
                               "use the number of coefficients in the source set."),
        "window": Param(Interval("min_length", math.inf, integer=True), "None: whole-series denoising — non-causal, "
                        "l_k depends on future samples. An integer w: causal sliding mode — l_k is the last value of "
                        "the denoised window x[k−w+1 .. k]; for k < w − 1 the available prefix x[0 .. k] is denoised "
                        "instead, and the first ``min_length − 1`` samples (too short for a level-deep "
                        "decomposition) pass through unchanged.", optional=True),
    }

    def __init__(self, wavelet: str = "db3", level: int = 3, threshold: str = "rigrsure",
                 mode: str = "soft", scaling: str = "one", scope: str = "global",
                 global_source: str = "coarsest", window: int | None = None):
        self._assign(locals())

    @functools.cached_property
    def _wavelet(self) -> pywt.Wavelet:
        import pywt

        return pywt.Wavelet(self.wavelet)

    @property
    def min_length(self) -> int:
        """(dec_len − 1)·2**level: the shortest series decomposed to ``level`` (Notes); the window's lower bound."""
        return (self._wavelet.dec_len - 1) * 2 ** self.level

    @property
    def is_causal(self) -> bool:
        """True in sliding-window mode: l_k uses only samples up to k."""
        return self.window is not None

    def describe(self) -> dict:
        """Flat description for logs and results, including whether it was causal."""
        return {
            "denoiser": "wavelet",
            "wavelet": self.wavelet,
            "level": self.level,
            "threshold": self.threshold,
            "mode": self.mode,
            "scaling": self.scaling,
            "scope": self.scope,
            "global_source": self.global_source,
            "window": self.window,
            "causal": self.is_causal,
            "causality": (f"causal sliding window of {self.window} samples" if self.is_causal
                          else "non-causal whole-series"),
        }

    def __repr__(self) -> str:
        d = self.describe()
        return (f"WaveletDenoiser(wavelet={self.wavelet!r}, level={self.level}, "
                f"threshold={self.threshold!r}, mode={self.mode!r}, scaling={self.scaling!r}, "
                f"scope={self.scope!r}, global_source={self.global_source!r}, "
                f"window={self.window!r})  # {d['causality']}")

    def denoise(self, x) -> np.ndarray:
        """Denoise sequences along the last axis: {L_k} → {l_k} (paper 000, §3.2).

        Parameters
        ----------
        x : array_like, shape (..., n)
            Chart statistics; every leading index is an independent sequence.
            Must be finite; whole-series mode needs n ≥ :attr:`min_length`.

        Returns
        -------
        ndarray, shape (..., n)
        """
        values = np.asarray(x, dtype=float)
        if values.ndim == 0:
            raise ValueError("denoise needs sequences along the last axis, got a scalar")
        if not np.all(np.isfinite(values)):
            raise ValueError("denoise got non-finite values (NaN/inf); wavelets would spread them")
        n = values.shape[-1]
        rows = values.reshape(-1, n)
        if self.window is None:
            if n < self.min_length:
                raise ValueError(f"whole-series denoising needs at least {self.min_length} samples "
                                 f"for {self.wavelet} at level {self.level}; got {n}")
            out = self._denoise_rows(rows)
        else:
            out = self._denoise_causal(rows)
        return out.reshape(values.shape)

    def _denoise_rows(self, rows: np.ndarray) -> np.ndarray:
        """Whole-series denoising of every row of a 2-D array.

        Runs the compiled kernel (:mod:`mosd.kernels.wavelet`, bit-identical) when
        the kernels are enabled and support this setting, else :meth:`_denoise_rows_numpy`.
        """
        from .. import kernels

        # the kernel implements this module's own rules; a replaced select_threshold (a test's) is honoured
        if kernels.enabled() and select_threshold is _KERNEL_RULES:
            plan = self._kernel_plan()
            if plan is not None and plan.fits(rows.shape[-1]):
                return plan(rows)
        return self._denoise_rows_numpy(rows)

    def _kernel_plan(self):
        """The compiled kernel's plan for this denoiser (None where it does not apply), made once."""
        if "_plan" not in self.__dict__:
            from ..kernels.wavelet import plan

            self.__dict__["_plan"] = plan(self)
        return self.__dict__["_plan"]

    def _denoise_rows_numpy(self, rows: np.ndarray) -> np.ndarray:
        """The reference: PyWavelets' wavedec, the threshold rule, wthresh, waverec."""
        import pywt

        n = rows.shape[-1]
        coeffs = pywt.wavedec(rows, self._wavelet, mode="symmetric", level=self.level, axis=-1)
        details = coeffs[1:]  # coarsest first: cD_level, ..., cD_1
        sigmas = self._noise_scales(details)
        thresholds = self._thresholds(details, sigmas)
        shrunk = [coeffs[0]] + [threshold_coefficients(d, t, self.mode)
                                for d, t in zip(details, thresholds)]
        # Odd lengths reconstruct one sample too long; MATLAB's waverec trims the same way.
        return pywt.waverec(shrunk, self._wavelet, mode="symmetric", axis=-1)[:, :n]

    def _noise_scales(self, details: list[np.ndarray]) -> list[np.ndarray]:
        """σ̂ per row (shape (B, 1)) for each detail level, as wden's SCAL."""
        rows = details[0].shape[0]
        if self.scaling == "one":
            return [np.ones((rows, 1))] * len(details)
        if self.scaling == "sln":
            sigma = np.median(np.abs(details[-1]), axis=-1, keepdims=True) / _MAD_TO_SIGMA
            return [sigma] * len(details)
        return [np.median(np.abs(d), axis=-1, keepdims=True) / _MAD_TO_SIGMA for d in details]

    def _thresholds(self, details: list[np.ndarray], sigmas: list[np.ndarray]) -> list[np.ndarray]:
        """Absolute threshold per row (shape (B, 1)) for each detail level."""
        # wden's guard: a σ̂ that is negligible against the coefficients means "no
        # noise to remove" — keep the details rather than divide by ~0.
        if self.scaling == "one":
            usable = [np.ones_like(s, dtype=bool) for s in sigmas]
        else:
            usable = [s > math.sqrt(np.finfo(float).eps) * np.max(np.abs(d), axis=-1, keepdims=True)
                      for d, s in zip(details, sigmas)]
        safe = [np.where(u, s, 1.0) for u, s in zip(usable, sigmas)]
        normalised = [d / s for d, s in zip(details, safe)]
        if self.scope == "level":
            unit = [select_threshold(z, self.threshold)[:, None] for z in normalised]
        else:
            if self.global_source == "all":
                source = np.concatenate(normalised, axis=-1)
            elif self.global_source == "finest":
                source = normalised[-1]
            else:
                source = normalised[0]
            unit = [select_threshold(source, self.threshold)[:, None]] * len(details)
        return [np.where(u, t * s, 0.0) for t, s, u in zip(unit, safe, usable)]

    def causal_tail(self, history: np.ndarray, n_new: int, first: int) -> np.ndarray:
        """The causal denoised values of the last ``n_new`` points of ``history`` (a stream's causal form).

        ``history`` holds, oldest first, up to ``window − 1`` earlier raw values and then the new ones; its
        first value is point ``first`` (0-based) of the stream. Point k's value is the last of the
        denoised x[max(0, k−w+1) .. k] (points before ``min_length − 1`` pass through): what
        :meth:`denoise` gives for the whole series, window by window, bit for bit.
        """
        history = np.asarray(history, float)
        w, out = self.window, np.empty(n_new)
        ends = np.arange(len(history) - n_new, len(history))            # positions of the new points in history
        lengths = np.minimum(first + ends + 1, w)                       # the window (or prefix) of each
        for length in np.unique(lengths):
            at = np.flatnonzero(lengths == length)
            if length < self.min_length:
                out[at] = history[ends[at]]
                continue
            windows = np.stack([history[e - length + 1:e + 1] for e in ends[at]])
            out[at] = self._denoise_rows(windows)[:, -1]
        return out

    def _denoise_causal(self, rows: np.ndarray) -> np.ndarray:
        """Causal sliding-window denoising of every row (see class docstring)."""
        n_rows, n = rows.shape
        w = self.window
        out = rows.copy()  # samples before min_length - 1 pass through
        # Growing prefixes: one batched call per prefix length, vectorised over rows.
        for length in range(self.min_length, min(w, n + 1)):
            out[:, length - 1] = self._denoise_rows(rows[:, :length])[:, -1]
        if n < w:
            return out
        windows = sliding_window_view(rows, w, axis=-1)  # (B, n - w + 1, w), a view
        n_windows = windows.shape[1]
        per_chunk = max(1, _CAUSAL_CHUNK_ELEMENTS // (w * n_rows))
        for start in range(0, n_windows, per_chunk):
            stop = min(start + per_chunk, n_windows)
            batch = windows[:, start:stop].reshape(-1, w)
            out[:, w - 1 + start:w - 1 + stop] = self._denoise_rows(batch)[:, -1].reshape(n_rows, -1)
        return out


__all__ = [
    "GLOBAL_SOURCES",
    "SCALINGS",
    "SCOPES",
    "THRESHOLD_MODES",
    "THRESHOLD_RULES",
    "WaveletDenoiser",
    "select_threshold",
    "threshold_coefficients",
]

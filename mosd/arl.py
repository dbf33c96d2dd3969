"""Average run lengths (ARL) of control charts.

Two tools:

* :func:`ewma_arl` — the exact-in-the-limit zero-state ARL of the two-sided EWMA
  chart with fixed asymptotic limits, by an integral equation (Crowder 1987,
  Nyström method with Gauss–Legendre quadrature) or by a Markov-chain
  approximation (Brook & Evans 1972).
* :func:`monte_carlo_arl` — the zero-state ARL of *any* chart that exposes
  ``alarms(Z)``, by simulating in-control or shifted subgroups.

docs/DECISIONS.md §7: run lengths are zero-state (every statistic starts at its
in-control value), and ARL0 of EWMA-type charts is never derived from a false-alarm
rate, because their alarms are autocorrelated.

References
----------
D. Brook and D. A. Evans (1972), An approach to the probability distribution of
CUSUM run length, Biometrika 59, 539–549.
S. V. Crowder (1987), A simple method for studying run-length distributions of
exponentially weighted moving average charts, Technometrics 29, 401–407.
J. M. Lucas and M. S. Saccucci (1990), Exponentially weighted moving average
control schemes: properties and enhancements, Technometrics 32, 1–12.
"""
from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np
from scipy import special

from .validation import ConfigError, Interval, check_choice, check_in, check_int

_LAM_RANGE = Interval(0.0, 1.0, open_low=True)
_L_RANGE = Interval(0.0, math.inf, open_low=True)
_SHIFT_RANGE = Interval(-math.inf, math.inf)

#: Default quadrature nodes (integral equation, a floor) and states (Markov
#: chain). The Markov chain's error falls like 1/states², the Nyström solution's
#: geometrically; tests/test_arl.py measures both.
_DEFAULT_NODES = 50
_DEFAULT_STATES = 301

#: Upper bound on the number of float64 kernel entries built at once, so that a
#: large grid of (λ, L, shift) is solved in chunks of batched linear systems.
_KERNEL_BUDGET = 4_000_000


class ArlEstimate(NamedTuple):
    """A Monte Carlo ARL: the mean run length and its standard error."""

    mean: float
    stderr: float


# --------------------------------------------------------------------------------------
# EWMA ARL by integral equation or Markov chain
# --------------------------------------------------------------------------------------
def ewma_arl(lam, L, shift=0.0, method: str = "integral", nodes: int | None = None):
    """Zero-state ARL of the two-sided EWMA chart with fixed asymptotic limits.

    The chart is E_k = (1−λ)E_{k−1} + λX_k, E_0 = 0, X_k ~ N(shift, 1) i.i.d.
    (paper 000 eqs. 21–22 with U_k in place of X_k), and it signals at the first k
    with |E_k| > h, h = L·sqrt(λ/(2−λ)) (the limit of eq. 29 as k → ∞).

    With g(u) the ARL started from E_0 = u, conditioning on E_1 gives Crowder's
    integral equation

        g(u) = 1 + (1/λ) ∫_{−h}^{h} g(v) φ((v − (1−λ)u)/λ − shift) dv,

    and the ARL is g(0).

    Parameters
    ----------
    lam : float or array_like, in (0, 1]
        Smoothing parameter λ; λ = 1 is the Shewhart chart.
    L : float or array_like, > 0
        Limit width in asymptotic standard deviations of E_k.
    shift : float or array_like
        Mean of X_k in its own standard deviations (0 = in control).
    method : {"integral", "markov"}
        ``"integral"`` (default, the more accurate): Nyström solution of the
        equation above with ``nodes`` Gauss–Legendre nodes on [−h, h].
        ``"markov"``: Brook & Evans's chain on ``nodes`` equal cells of [−h, h]
        (an odd number, so that one cell is centred on E_0 = 0); its error falls
        like 1/nodes².
    nodes : int, optional
        Quadrature nodes or Markov states. Default for ``"integral"``: 50, more
        for small λ or wide limits (6 per unit of h/λ, in steps of 25), which
        gives 1e-8 relative accuracy or better up to ARLs of ~1e6; for
        ``"markov"``: 301 states, within 0.2 % of the integral solution for
        λ ≥ 0.05 and L ≤ 3.

    Returns
    -------
    float or ndarray
        A float when every argument is a scalar, else an array of the broadcast
        shape of ``lam``, ``L`` and ``shift``.

    Raises
    ------
    ConfigError
        When ``lam`` is outside (0, 1], ``L`` ≤ 0, ``shift`` is not finite, or
        ``method``/``nodes`` are not allowed.
    """
    method = check_choice("method", method, ("integral", "markov"))
    if nodes is not None:
        nodes = check_int("nodes", nodes, 2 if method == "integral" else 1)
    if method == "markov" and nodes is not None and nodes % 2 == 0:
        raise ConfigError(f"nodes={nodes!r} is even; allowed: odd integers for method='markov'")
    lam_arr = _checked_array("lam", lam, _LAM_RANGE)
    L_arr = _checked_array("L", L, _L_RANGE)
    shift_arr = _checked_array("shift", shift, _SHIFT_RANGE)
    lam_b, L_b, shift_b = np.broadcast_arrays(lam_arr, L_arr, shift_arr)
    shape = lam_b.shape
    lam_f, L_f, shift_f = (np.ravel(x) for x in (lam_b, L_b, shift_b))
    half_width = L_f * np.sqrt(lam_f / (2.0 - lam_f))

    if method == "integral":
        solve = _ewma_arl_integral
        node_counts = _integral_nodes(lam_f, L_f) if nodes is None else np.full(lam_f.size, nodes)
    else:
        solve = _ewma_arl_markov
        node_counts = np.full(lam_f.size, _DEFAULT_STATES if nodes is None else nodes)
    arl = np.empty(lam_f.size)
    # parameter sets that need the same number of nodes are solved as one batch of linear systems
    for count in np.unique(node_counts):
        members = np.flatnonzero(node_counts == count)
        chunk = max(1, _KERNEL_BUDGET // int(count) ** 2)
        for start in range(0, members.size, chunk):
            part = members[start:start + chunk]
            arl[part] = solve(lam_f[part], half_width[part], shift_f[part], int(count))
    if shape == ():
        return float(arl[0])
    return arl.reshape(shape)


def _integral_nodes(lam, L):
    """Default Gauss–Legendre node count per parameter set, in steps of 25.

    The kernel of Crowder's equation is a Gaussian of sd λ on an interval of
    half-width h, so the nodes needed grow with h/λ = L/sqrt(λ(2−λ)). Measured
    here against three times as many nodes: 6 nodes per unit of h/λ (at least
    50) keep the relative error below 1e-8 for λ in [0.001, 1], L in [0.5, 4],
    |shift| ≤ 4. Beyond ARLs of ~1e6 rounding dominates (I − K is then nearly
    singular; its condition number grows with the ARL): measured 2e-8 at
    ARL ≈ 2e6, 5e-6 at ARL ≈ 5e8.
    """
    needed = 6.0 * L / np.sqrt(lam * (2.0 - lam))
    return np.maximum(_DEFAULT_NODES, 25 * np.ceil(needed / 25.0)).astype(int)


def _ewma_arl_integral(lam, half_width, shift, nodes):
    """Nyström solution of Crowder's equation for a batch of parameter sets (B,)."""
    unit_nodes, unit_weights = np.polynomial.legendre.leggauss(nodes)
    # nodes and weights mapped from [−1, 1] to [−h, h] for each parameter set: (B, N)
    x = half_width[:, None] * unit_nodes
    w = half_width[:, None] * unit_weights
    lam_, shift_ = lam[:, None, None], shift[:, None, None]
    # kernel[b, i, j] = w_j/λ · φ((x_j − (1−λ)x_i)/λ − shift): density of E_1 = x_j from E_0 = x_i
    standardised = (x[:, None, :] - (1.0 - lam_) * x[:, :, None]) / lam_ - shift_
    kernel = w[:, None, :] / lam_ * _normal_pdf(standardised)
    system = np.eye(nodes) - kernel
    g = np.linalg.solve(system, np.ones((lam.size, nodes, 1)))[..., 0]
    # Nyström interpolation: evaluate the equation's right-hand side at u = 0 exactly
    from_zero = w / lam[:, None] * _normal_pdf(x / lam[:, None] - shift[:, None])
    return 1.0 + np.sum(from_zero * g, axis=1)


def _ewma_arl_markov(lam, half_width, shift, states):
    """Brook–Evans Markov-chain ARL for a batch of parameter sets (B,)."""
    cell = 2.0 * half_width[:, None] / states
    edges = -half_width[:, None] + cell * np.arange(states + 1)  # (B, N+1)
    centres = 0.5 * (edges[:, :-1] + edges[:, 1:])  # (B, N)
    lam_, shift_ = lam[:, None, None], shift[:, None, None]
    # transition[b, i, j] = P(E_1 in cell j | E_0 = centre i)
    standardised = (edges[:, None, :] - (1.0 - lam_) * centres[:, :, None]) / lam_ - shift_
    cdf = special.ndtr(standardised)
    transition = np.diff(cdf, axis=-1)
    system = np.eye(states) - transition
    g = np.linalg.solve(system, np.ones((lam.size, states, 1)))[..., 0]
    return g[:, states // 2]


def _normal_pdf(x):
    return np.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)


def _checked_array(name: str, value, interval: Interval) -> np.ndarray:
    """``value`` as a float array, or ConfigError naming the first element out of ``interval``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}={value!r} is not a number; allowed: {interval}") from None
    if arr.ndim == 0:
        check_in(name, value, interval)
    inside = _vector_inside(arr, interval)
    if not inside.all():
        bad = float(arr[~inside].flat[0])
        raise ConfigError(f"{name} contains {bad!r}, out of range; allowed: {interval}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name}={value!r} is not finite; allowed: finite numbers in {interval}")
    return arr


def _vector_inside(values: np.ndarray, interval: Interval) -> np.ndarray:
    low_ok = values > interval.low if interval.open_low else values >= interval.low
    high_ok = values < interval.high if interval.open_high else values <= interval.high
    return low_ok & high_ok


# --------------------------------------------------------------------------------------
# Monte Carlo ARL of any chart
# --------------------------------------------------------------------------------------
#: First simulated horizon; unresolved replications are re-simulated with the
#: horizon doubled. The run lengths do not depend on it (see monte_carlo_arl).
_FIRST_HORIZON = 64

#: Default number of standardised values simulated per call to chart.alarms.
_VALUE_BUDGET = 1 << 21


def monte_carlo_arl(chart, a: float = 0.0, b: float = 1.0, n: int = 5, reps: int = 2000, seed: int = 0,
                    max_run: int = 100_000, batch: int | None = None) -> ArlEstimate:
    """Zero-state ARL of ``chart`` by Monte Carlo simulation.

    Each replication is a sequence of i.i.d. subgroups of size ``n`` whose values
    are N(a, b²) in units of the in-control σ (in control: a = 0, b = 1, the
    standardisation the monitor applies). The sequences are fed to
    ``chart.alarms(Z)`` with Z of shape (replications, T, n); the run length is
    the index of the first alarm plus one.

    Replications without an alarm in T samples are simulated again from their
    start with the horizon doubled (the chart is recursive, so its state at T
    cannot be resumed through ``alarms``), until every replication has alarmed or
    T reaches ``max_run``. Every replication draws from its own generator,
    spawned from ``np.random.SeedSequence(seed)``, and re-drawing a longer
    horizon from the same generator reproduces the shorter one as its prefix.
    Hence each run length is a function of (seed, replication index) alone: the
    result does not depend on ``batch`` nor on the horizon schedule, provided the
    chart is causal (its alarm at k uses subgroups 1..k only).

    Parameters
    ----------
    chart : object with ``alarms(Z) -> bool ndarray (R, T)``
        A causal chart, fitted if its limit needs Phase-I data.
    a : float
        Mean shift of every value, in in-control σ.
    b : float, > 0
        Standard-deviation ratio of every value to the in-control σ.
    n : int, ≥ 1
        Subgroup size.
    reps : int, ≥ 2
        Number of replications (run lengths).
    seed : int, ≥ 0
        Seed of the SeedSequence the replications' generators are spawned from.
    max_run : int, ≥ 1
        Longest run simulated. Runs without an alarm by then are counted as
        ``max_run`` (censored; a RuntimeWarning says how many), so the mean is then
        a lower bound.
    batch : int, optional
        Replications per call to ``chart.alarms`` (memory control only). Default:
        as many as keep one call at about 2 million simulated values.

    Returns
    -------
    ArlEstimate
        ``(mean, stderr)`` with stderr = sd(run lengths)/√reps.

    Raises
    ------
    ConfigError
        On an invalid parameter, a chart without ``alarms`` or a non-causal one.
    ValueError
        When ``chart.alarms`` returns an array of the wrong shape.
    """
    if not callable(getattr(chart, "alarms", None)):
        raise ConfigError(f"chart={chart!r} has no alarms(Z) method; allowed: a chart object")
    causal = getattr(chart, "is_causal", None)
    if causal is None:
        causal = getattr(getattr(chart, "denoiser", None), "is_causal", True)
    if not causal:
        raise ConfigError(f"chart={chart!r} is not causal (whole-series denoising); allowed: causal charts, "
                          "whose run length does not depend on the simulated horizon")
    a = check_in("a", a, Interval(-math.inf, math.inf))
    if not math.isfinite(a):
        raise ConfigError(f"a={a!r} is not finite; allowed: finite numbers")
    b = check_in("b", b, Interval(0.0, math.inf, open_low=True, open_high=True))
    n = check_int("n", n, 1)
    reps = check_int("reps", reps, 2)
    seed = check_int("seed", seed, 0)
    max_run = check_int("max_run", max_run, 1)
    if batch is not None:
        batch = check_int("batch", batch, 1)

    streams = np.random.SeedSequence(seed).spawn(reps)
    run_length = np.zeros(reps, dtype=np.int64)
    unresolved = np.arange(reps)
    horizon = min(_FIRST_HORIZON, max_run)
    while True:
        per_call = batch if batch is not None else max(1, _VALUE_BUDGET // (horizon * n))
        for start in range(0, unresolved.size, per_call):
            chunk = unresolved[start:start + per_call]
            z = a + b * _draw_subgroups([streams[r] for r in chunk], horizon, n)
            alarm = np.asarray(chart.alarms(z))
            if alarm.shape != (chunk.size, horizon):
                raise ValueError(f"chart.alarms returned shape {alarm.shape}; expected {(chunk.size, horizon)}")
            fired = alarm.any(axis=1)
            run_length[chunk[fired]] = np.argmax(alarm[fired], axis=1) + 1
        unresolved = unresolved[run_length[unresolved] == 0]
        if unresolved.size == 0:
            break
        if horizon >= max_run:
            run_length[unresolved] = max_run
            warnings.warn(f"{unresolved.size} of {reps} runs had no alarm within max_run={max_run}; "
                          "counted as max_run, so the ARL is underestimated", RuntimeWarning, stacklevel=2)
            break
        horizon = min(2 * horizon, max_run)

    mean = float(run_length.mean())
    stderr = float(run_length.std(ddof=1) / math.sqrt(reps))
    return ArlEstimate(mean, stderr)


def _draw_subgroups(streams: list[np.random.SeedSequence], horizon: int, n: int) -> np.ndarray:
    """Standard normal subgroups (len(streams), horizon, n), one generator per replication.

    A fresh generator per call makes the draw of a longer horizon start with the
    draw of a shorter one (standard_normal fills its output in C order, one value
    after another), which is what makes the run lengths horizon-independent.
    """
    out = np.empty((len(streams), horizon, n))
    for row, stream in enumerate(streams):
        np.random.Generator(np.random.PCG64(stream)).standard_normal(out=out[row])
    return out

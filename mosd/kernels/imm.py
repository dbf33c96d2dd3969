"""Paper 001's asynchronous IMM fusion filter (:class:`mosd.estimators.AsyncIMMFusion`), compiled.

One compiled call runs the whole time loop of every replication it is given:
at each fusion instant t_k the IMM mixing (§3.1), the fault-conditioned
filtering of every model over (t_{k−1}, t_k] (§3.2: Theorem 1's equivalent
measurement, or measurement-by-measurement updates, as the estimator's
``fusion`` selects), the mode-probability update (§3.3) and the output fusion
(§3.4). The algebra and its order are those of the NumPy reference in
:mod:`mosd.estimators.async_imm`; what the loop does not reproduce is the
arithmetic inside BLAS/LAPACK (OpenBLAS's small products use fused
multiply-adds; the reference solves by LU, this loop by Cholesky), so the
results are not bit-identical but agree to ~1e-14 relative to each vector or
matrix, 4e-13 at worst on amplitudes near 0 (``tests/test_kernel_imm.py``
checks 1e-12 on every output).

What stays in Python
--------------------
Φ(Δ), Γ(Δ)u and Q_d(Δ) need a matrix exponential. They depend on Δ only, and a
run has few distinct Δ (sample instants on the plant's grid), so
:func:`filter_batch` collects every interval the loop will need, asks the
estimator's own cache for each distinct one (the same rounding of Δ to 1e-12 s,
so the same matrices as the reference) and hands the kernel a table plus one
table index per slot. For the equivalent measurement it also tabulates
H̄ = H Φ⁻¹, H̄Γu and C = −Q H̄ᵀ per (Δ, sensor, model) with the reference's own
NumPy expressions.

Replications are independent; :func:`filter_batch` splits them over threads
(the kernel releases the GIL), which changes no number.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile

from .cubature import _over_replications, _solve_columns

_LOG_2PI = math.log(2.0 * math.pi)


#: The loop's steps, each a function of its own to read, inlined into :func:`imm` by numba (their IR, before
#: typing): the compiled loop is the one body it was when written in one piece, the same operations in the same
#: order, with no call and no second compile of a step. Each array an inlined step receives is a new reference
#: that numba counts in and out, so a step is called once per fusion instant with its loops over the models and
#: packets inside it (a step per packet and model cost the sequential loop 26 %, 200 runs of 41 s, one thread),
#: and the prediction indexes model i instead of receiving five views of it, which pays for the rest.
_step = njit(inline="always", nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)


@njit(cache=True, nogil=True, error_model="numpy")
def _cholesky(a, n, low):
    """Lower L with L Lᵀ = a[:n, :n] (column by column, as LAPACK's potf2); False if not positive definite."""
    for j in range(n):
        dot = 0.0
        for c in range(j):
            dot += low[j, c] * low[j, c]
        pivot = a[j, j] - dot
        if not pivot > 0.0:  # also catches NaN
            return False
        ljj = math.sqrt(pivot)
        low[j, j] = ljj
        for i in range(j + 1, n):
            dot = 0.0
            for c in range(j):
                dot += low[i, c] * low[j, c]
            low[i, j] = (a[i, j] - dot) / ljj
        for i in range(j):
            low[i, j] = 0.0
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def _white_logdet(low, n, nu, white):
    """(Σ w², log det S) with L w = ν: the two data terms of log N(ν; 0, S); ``white`` is workspace."""
    sumsq = 0.0
    logdet = 0.0
    for a in range(n):
        acc = nu[a]
        for b in range(a):
            acc -= low[a, b] * white[b]
        white[a] = acc / low[a, a]
        sumsq += white[a] * white[a]
        logdet += math.log(low[a, a])
    return sumsq, 2.0 * logdet


@_step
def _predict(x, P, i, phi, drive, q, row, tmp, xn):
    """x_i ← Φ x_i + Γu, P_i ← sym(Φ P_i Φᵀ + Q) in place, for model i over table row ``row`` (the reference's
    ``predict``). Indexed, not handed views of model i: no new array per model and packet."""
    n = x.shape[1]
    for a in range(n):
        acc = 0.0
        for b in range(n):
            acc += phi[row, i, a, b] * x[i, b]
        xn[a] = acc + drive[row, i, a]
    for a in range(n):
        x[i, a] = xn[a]
    for a in range(n):
        for b in range(n):
            acc = 0.0
            for c in range(n):
                acc += phi[row, i, a, c] * P[i, c, b]
            tmp[a, b] = acc
    for a in range(n):
        for b in range(n):
            acc = 0.0
            for c in range(n):
                acc += tmp[a, c] * phi[row, i, b, c]
            P[i, a, b] = acc + q[row, i, a, b]
    _symmetrise(P[i], n)


@njit(cache=True, nogil=True, error_model="numpy")
def _symmetrise(a, n):
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (a[i, j] + a[j, i])
            a[i, j] = v
            a[j, i] = v
        a[i, i] = 0.5 * (a[i, i] + a[i, i])


@_step
def _start(mu0, x0, P0, mu, x, P):
    """Each model's μ, x̂ and P before row 0 (copied: the loop updates them in place)."""
    n_models, n = x0.shape
    for i in range(n_models):
        mu[i] = mu0[i]
        for a in range(n):
            x[i, a] = x0[i, a]
            for b in range(n):
                P[i, a, b] = P0[i, a, b]


@_step
def _restart(mu, x, P, trans, cbar, weights, xm, Pm, d):
    """§3.1 filter restart (eqs. 20–23): c̄_m = Σ_i λ_im μ_i, μ_{i|m} = λ_im μ_i / c̄_m, x and P mixed in place.

    A model no model reaches (c̄_m = 0) keeps its own estimate. ``cbar`` is filled (the mode update uses it);
    ``weights``, ``xm``, ``Pm`` and ``d`` are workspace.
    """
    n_models, n = x.shape
    for j in range(n_models):
        acc = 0.0
        for i in range(n_models):
            acc += mu[i] * trans[i, j]
        cbar[j] = acc
    for i in range(n_models):
        for j in range(n_models):
            if cbar[j] > 0.0:
                weights[i, j] = mu[i] * trans[i, j] / cbar[j]
            else:
                weights[i, j] = 1.0 if i == j else 0.0
    for j in range(n_models):
        for a in range(n):
            acc = 0.0
            for i in range(n_models):
                acc += weights[i, j] * x[i, a]
            xm[j, a] = acc
        for a in range(n):
            for b in range(n):
                Pm[j, a, b] = 0.0
        for i in range(n_models):
            for a in range(n):
                d[a] = x[i, a] - xm[j, a]
            for a in range(n):
                for b in range(n):
                    Pm[j, a, b] += weights[i, j] * (P[i, a, b] + d[a] * d[b])
    x[:, :] = xm
    P[:, :, :] = Pm


@_step
def _sequential_interval(r, k, nv, x, P, y, sensor, slot_key, key, phi, drive, q, H, Rm, loglik, tmp, d, hq, nu, s,
                         low, pht_t, gain_t, white):
    """§3.2 by measurement-by-measurement updates over (t_{k−1}, t_k]; False where an S is not positive definite.

    Every model is predicted to each of the ``nv`` packets' instants τ_j and updated with it, in time order:
    S = H P Hᵀ + R, Kᵀ = S⁻¹ H P (Cholesky), x ← x + Kν, P ← sym(P − K H P), log N(ν; 0, S) summed into
    ``loglik``; then each model is predicted on to t_k (table row ``key``).
    """
    m, n = H.shape[1], H.shape[2]
    for j in range(nv):
        row = slot_key[r, k, j]
        sn = sensor[r, k, j]
        for i in range(x.shape[0]):
            _predict(x, P, i, phi, drive, q, row, tmp, d)
            for a in range(m):
                acc = 0.0
                for b in range(n):
                    acc += H[sn, a, b] * x[i, b]
                nu[a] = y[r, k, j, a] - acc
                for b in range(n):
                    acc = 0.0
                    for c in range(n):
                        acc += H[sn, a, c] * P[i, c, b]
                    hq[a, b] = acc
            for a in range(m):
                for b in range(m):
                    acc = 0.0
                    for c in range(n):
                        acc += hq[a, c] * H[sn, b, c]
                    s[a, b] = acc + Rm[sn, a, b]
            _symmetrise(s, m)
            if not _cholesky(s, m, low):
                return False
            for a in range(m):
                for b in range(n):
                    pht_t[a, b] = hq[a, b]
            _solve_columns(low, m, pht_t, n, gain_t)
            for b in range(n):
                acc = 0.0
                for a in range(m):
                    acc += nu[a] * gain_t[a, b]
                x[i, b] = x[i, b] + acc
            for a in range(n):
                for b in range(n):
                    acc = 0.0
                    for c in range(m):
                        acc += gain_t[c, a] * hq[c, b]
                    P[i, a, b] = P[i, a, b] - acc
            _symmetrise(P[i], n)
            sumsq, logdet = _white_logdet(low, m, nu, white)
            loglik[i] += -0.5 * (sumsq + logdet + m * _LOG_2PI)
    for i in range(x.shape[0]):
        _predict(x, P, i, phi, drive, q, key, tmp, d)
    return True


@_step
def _stack_slots(r, k, nv, y, sensor, slot_key, h_eq, hgu, cross, q, Rm, hq, z_bar, h_bar, c_bar, r_bar):
    """Theorem 1's stacked equivalent measurement z̄ = H̄ x(t_k) + ṽ over the interval's ``nv`` slots, every model.

    Rows j·m..(j+1)·m of ``z_bar[i]`` (y_j + H̄_j Γu), ``h_bar[i]`` (H̄_j = H Φ⁻¹), columns of ``c_bar[i]``
    (C_j = −Q H̄_jᵀ), and Lemma 2's covariance ``r_bar[i]``: R̃_ij = δ_ij R_s(i) + H̄_i Q_max(i,j) H̄_jᵀ.
    """
    n_models, m, n = h_eq.shape[2], h_eq.shape[3], h_eq.shape[4]
    for i in range(n_models):
        for j in range(nv):
            kj = slot_key[r, k, j]
            sj = sensor[r, k, j]
            for a in range(m):
                z_bar[i, j * m + a] = y[r, k, j, a] + hgu[kj, sj, i, a]
                for b in range(n):
                    h_bar[i, j * m + a, b] = h_eq[kj, sj, i, a, b]
                    c_bar[i, b, j * m + a] = cross[kj, sj, i, b, a]
        for j1 in range(nv):
            k1 = slot_key[r, k, j1]
            s1 = sensor[r, k, j1]
            for j2 in range(nv):
                if j2 == 0 or j2 > j1:
                    # H̄_j1 Q_max(j1,j2): one product for every j2 <= j1, one per later j2
                    later = slot_key[r, k, max(j1, j2)]
                    for a in range(m):
                        for b in range(n):
                            acc = 0.0
                            for c in range(n):
                                acc += h_eq[k1, s1, i, a, c] * q[later, i, c, b]
                            hq[a, b] = acc
                k2 = slot_key[r, k, j2]
                s2 = sensor[r, k, j2]
                for a in range(m):
                    for b in range(m):
                        acc = 0.0
                        for c in range(n):
                            acc += hq[a, c] * h_eq[k2, s2, i, b, c]
                        if j1 == j2:
                            acc += Rm[s1, a, b]
                        r_bar[i, j1 * m + a, j2 * m + b] = acc


@_step
def _stacked_updates(x, P, rows, h_bar, c_bar, r_bar, z_bar, pht_c, s, nu, low, pht_t, gain_t, sg, white, logpdf):
    """Theorem 1's update of every model with its stacked measurement (``rows`` rows); x and P in place.

    S = H̄ (P H̄ᵀ + C) + Cᵀ H̄ᵀ + R̃, Kᵀ = S⁻¹ (P H̄ᵀ + C)ᵀ, x ← x + Kν, P ← sym(P − K S Kᵀ); ``logpdf[i]`` the two
    data terms of log N(ν; 0, S), Σ w² + log det S with L w = ν (0 for no rows). False where an S is not positive
    definite.
    """
    n_models, n = x.shape
    for i in range(n_models):
        for a in range(n):
            for b in range(rows):
                acc = 0.0
                for c in range(n):
                    acc += P[i, a, c] * h_bar[i, b, c]
                pht_c[a, b] = acc + c_bar[i, a, b]
        for a in range(rows):
            for b in range(rows):
                acc = 0.0
                for c in range(n):
                    acc += h_bar[i, a, c] * pht_c[c, b]
                acc2 = 0.0
                for c in range(n):
                    acc2 += c_bar[i, c, a] * h_bar[i, b, c]
                s[a, b] = acc + acc2 + r_bar[i, a, b]
        _symmetrise(s, rows)
        for a in range(rows):
            acc = 0.0
            for b in range(n):
                acc += h_bar[i, a, b] * x[i, b]
            nu[a] = z_bar[i, a] - acc
        if rows > 0:
            if not _cholesky(s, rows, low):
                return False
            for a in range(rows):
                for b in range(n):
                    pht_t[a, b] = pht_c[b, a]
            _solve_columns(low, rows, pht_t, n, gain_t)  # Kᵀ = S⁻¹ (P H̄ᵀ + C)ᵀ
        for b in range(n):
            acc = 0.0
            for a in range(rows):
                acc += nu[a] * gain_t[a, b]
            x[i, b] = x[i, b] + acc
        # P − Kᵀᵀ S Kᵀ, as the reference: (Kᵀᵀ S) Kᵀ
        for a in range(n):
            for b in range(rows):
                acc = 0.0
                for c in range(rows):
                    acc += gain_t[c, a] * s[c, b]
                sg[a, b] = acc
        for a in range(n):
            for b in range(n):
                acc = 0.0
                for c in range(rows):
                    acc += sg[a, c] * gain_t[c, b]
                P[i, a, b] = P[i, a, b] - acc
        _symmetrise(P[i], n)
        if rows > 0:
            sumsq, logdet = _white_logdet(low, rows, nu, white)
        else:
            sumsq, logdet = 0.0, 0.0
        logpdf[i] = sumsq + logdet
    return True


@_step
def _mode_update(mu, cbar, loglik, log_post):
    """§3.3: μ_m ∝ Λ_m c̄_m, in logs (the largest term subtracted before the exponential); ``mu`` in place."""
    n_models = mu.shape[0]
    for i in range(n_models):
        # log 0 = −inf: a model no model can reach keeps probability 0
        log_post[i] = (math.log(cbar[i]) if cbar[i] > 0.0 else -np.inf) + loglik[i]
    top = log_post[0]
    for i in range(1, n_models):
        if log_post[i] > top:
            top = log_post[i]
    total = 0.0
    for i in range(n_models):
        log_post[i] = math.exp(log_post[i] - top)
        total += log_post[i]
    for i in range(n_models):
        mu[i] = log_post[i] / total


@_step
def _fuse(r, n_rows, out_mu, out_x, out_P, fused_x, fused_P, d):
    """§3.4 output fusion of rows 0..n_rows − 1 of replication r from each model's stored μ, x̂ and P:
    x̂ = Σ_m μ_m x̂_m, P = Σ_m μ_m [P_m + (x̂_m − x̂)(x̂_m − x̂)ᵀ].

    Once per replication, after its time loop, from the stored rows (the values the loop held: the same
    products in the same order), not once per row: fewer counted references in the loop.
    """
    n_models, n = out_x.shape[2], out_x.shape[3]
    for k in range(n_rows):
        for a in range(n):
            acc = 0.0
            for i in range(n_models):
                acc += out_mu[r, k, i] * out_x[r, k, i, a]
            fused_x[r, k, a] = acc
        for a in range(n):
            for b in range(n):
                fused_P[r, k, a, b] = 0.0
        for i in range(n_models):
            for a in range(n):
                d[a] = out_x[r, k, i, a] - fused_x[r, k, a]
            for a in range(n):
                for b in range(n):
                    fused_P[r, k, a, b] += out_mu[r, k, i] * (out_P[r, k, i, a, b] + d[a] * d[b])


@njit(cache=True, nogil=True, error_model="numpy")
def imm(sequential, counts, n_valid, y, sensor, slot_key, step_key, phi, drive, q, h_eq, hgu, cross, H, Rm,
        trans, mu0, x0, P0, first, stop, out_mu, out_x, out_P, out_ll, fused_x, fused_P, status):
    """Filter replications [first, stop) over every fusion instant; the compiled :meth:`AsyncIMMFusion.estimate`.

    Parameters
    ----------
    sequential : bool
        Measurement-by-measurement updates (else Theorem 1's equivalent measurement).
    counts : int64 (N,)
        Slots of interval k in the whole batch (``IntervalMeasurements.count``);
        the reference's likelihood constant depends on it.
    n_valid : int64 (R, N)
        Packets of replication r in interval k; they fill slots 0..n_valid − 1.
    y : float64 (R, N, J, m); sensor : int64 (R, N, J)
    slot_key : int64 (R, N, J)
        Table row of slot j's interval: τ_j − τ_{j−1} (sequential, τ_{−1} = t_{k−1})
        or t_k − τ_j (equivalent measurement).
    step_key : int64 (R, N)
        Table row of the prediction to t_k: t_k − τ_last (sequential) or t_k − t_{k−1}.
    phi, drive, q : float64 (K, M, n, n), (K, M, n), (K, M, n, n)
        Φ, Γu, Q_d of every model for each tabulated interval.
    h_eq, hgu, cross : float64 (K, S, M, m, n), (K, S, M, m), (K, S, M, n, m)
        H̄ = H Φ⁻¹, H̄ Γu and C = −Q H̄ᵀ (equivalent measurement only; else empty).
    H, Rm : float64 (S, m, n), (S, m, m)
    trans : float64 (M, M); mu0 : (M,); x0 : (M, n); P0 : (M, n, n)
        The state before row 0 of every replication: each model's μ, x̂ and P (a run's start: μ_0 and the
        augmented prior for every model; a stream's chunk: the state it carries). Row 0 is not updated.
    first, stop : int
        The replications this call filters (threads share the output arrays).
    out_mu, out_x, out_P, out_ll, fused_x, fused_P : filled
        (R, N, M), (R, N, M, n), (R, N, M, n, n), (R, N, M), (R, N, n), (R, N, n, n).
    status : int8 (R,), filled
        0, or 1 where an innovation covariance was not positive definite (the
        reference's Cholesky raises there; the caller then runs it).
    """
    n_models, n, m = mu0.shape[0], x0.shape[1], H.shape[1]
    big = max(y.shape[2] * m, m)  # the update's workspace: J·m rows at most
    mu, x, P, cbar = np.empty(n_models), np.empty((n_models, n)), np.empty((n_models, n, n)), np.empty(n_models)
    weights, xm, Pm = np.empty((n_models, n_models)), np.empty((n_models, n)), np.empty((n_models, n, n))
    d, tmp, loglik, log_post = np.empty(n), np.empty((n, n)), np.empty(n_models), np.empty(n_models)
    logpdf = np.empty(n_models)
    pht_c, pht_t, s, low = np.empty((n, big)), np.empty((big, n)), np.empty((big, big)), np.empty((big, big))
    gain_t, sg, nu, hq, white = np.empty((big, n)), np.empty((n, big)), np.empty(big), np.empty((m, n)), np.empty(big)
    # the stacked measurement of every model (Theorem 1)
    z_bar, h_bar = np.empty((n_models, big)), np.empty((n_models, big, n))
    c_bar, r_bar = np.empty((n_models, n, big)), np.empty((n_models, big, big))
    for r in range(first, stop):
        status[r] = 0
        _start(mu0, x0, P0, mu, x, P)
        for k in range(counts.shape[0]):
            if k > 0:
                _restart(mu, x, P, trans, cbar, weights, xm, Pm, d)
                nv, n_slots_k, key = n_valid[r, k], counts[k], step_key[r, k]
                for i in range(n_models):
                    loglik[i] = 0.0
                if sequential:  # §3.2, measurement by measurement
                    ok = _sequential_interval(r, k, nv, x, P, y, sensor, slot_key, key, phi, drive, q, H, Rm, loglik,
                                              tmp, d, hq, nu, s, low, pht_t, gain_t, white)
                else:  # §3.2, Theorem 1: every model predicted to t_k, then one update with the interval's packets
                    for i in range(n_models):
                        _predict(x, P, i, phi, drive, q, key, tmp, d)
                    ok = True
                    if n_slots_k > 0:
                        _stack_slots(r, k, nv, y, sensor, slot_key, h_eq, hgu, cross, q, Rm, hq, z_bar, h_bar, c_bar,
                                     r_bar)
                        ok = _stacked_updates(x, P, nv * m, h_bar, c_bar, r_bar, z_bar, pht_c, s, nu, low, pht_t,
                                              gain_t, sg, white, logpdf)
                        # the reference pads to the batch's slot count with unit blocks and adds their
                        # constant back; the same expression keeps the same rounding
                        for i in range(n_models):
                            loglik[i] = (-0.5 * (logpdf[i] + (n_slots_k * m) * _LOG_2PI)
                                         + 0.5 * m * _LOG_2PI * (n_slots_k - nv))
                if not ok:
                    status[r] = 1  # the reference's Cholesky raises here; the caller runs it
                    break
                _mode_update(mu, cbar, loglik, log_post)
            # row k: each model's μ, x̂, P and log Λ (0 at row 0); §3.4's fusion follows the time loop
            for i in range(n_models):
                out_mu[r, k, i] = mu[i]
                out_ll[r, k, i] = loglik[i] if k > 0 else 0.0
                for a in range(n):
                    out_x[r, k, i, a] = x[i, a]
                    for b in range(n):
                        out_P[r, k, i, a, b] = P[i, a, b]
        if status[r] == 0:
            _fuse(r, counts.shape[0], out_mu, out_x, out_P, fused_x, fused_P, d)


def _tables(step, deltas):
    """Table rows for ``deltas`` (any shape) and the (Φ, Γu, Q_d) table from the estimator's cache ``step``.

    Rows are the distinct Δ rounded to 1e-12 s, the key of the reference's
    cache; each row's matrices come from a representative Δ of that key, so they
    are the matrices the reference uses for every Δ with that key.
    """
    flat = np.asarray(deltas, float).ravel()
    keys, first, inverse = np.unique(np.round(flat, 12), return_index=True, return_inverse=True)
    phi, drive, q = step(flat[first])
    return inverse.reshape(np.shape(deltas)).astype(np.int64), phi, drive, q


def filter_batch(sequential, meas, grid, step, H, Rm, trans, mu0, x0, P0, threads=None):
    """The compiled IMM over every replication of ``meas``; None where the reference must decide.

    Parameters
    ----------
    sequential : bool
    meas : IntervalMeasurements
        The packets grouped by fusion interval (``t``, ``y``, ``sensor``, ``valid``).
    grid : ndarray (N,)
        Fusion instants.
    step : callable
        Δ (K,) → Φ (K, M, n, n), Γu (K, M, n), Q_d (K, M, n, n): the estimator's cache.
    H, Rm : ndarray (S, m, n), (S, m, m)
    trans, mu0, x0, P0 : the transition matrix, μ_0 and the augmented prior (x̂ (n,) or per model (M, n),
        P (n, n) or (M, n, n)): the state before row 0, which is not updated (the prior at t_0 of a run,
        or the state a stream carries, with ``grid[0]`` the previous fusion instant).
    threads : int, optional
        Threads to split the replications over (default :func:`mosd.kernels.threads`).

    Returns
    -------
    tuple or None
        (μ (R, N, M), x̂_m (R, N, M, n), P_m (R, N, M, n, n), log Λ_m (R, N, M),
        fused x̂ (R, N, n), fused P (R, N, n, n)); None when a packet's value is
        not finite or an innovation covariance is not positive definite (the
        reference then runs and decides: NaN propagation or LinAlgError).
    """
    valid = np.asarray(meas.valid, bool)
    n_reps, n_points, n_slots = valid.shape
    t = np.asarray(meas.t, float)
    y = np.ascontiguousarray(np.where(valid[..., None], meas.y, 0.0))
    if not np.all(np.isfinite(y)) or n_points < 2:
        return None
    n_valid = valid.sum(axis=-1).astype(np.int64)
    counts = n_valid.max(axis=0) if n_reps else np.zeros(n_points, np.int64)
    # valid packets fill the first n_valid slots of their interval, in time order
    slot = np.arange(n_slots)
    if not np.array_equal(valid, slot < n_valid[..., None]):
        return None
    previous = np.broadcast_to(np.r_[grid[0], grid[:-1]][None, :], (n_reps, n_points))
    if sequential:
        prior = np.concatenate([previous[..., None], t[..., :-1]], axis=-1)[..., :n_slots]
        slot_delta = np.where(valid, t - prior, 0.0)
        last = previous
        if n_slots:
            last = np.where(n_valid > 0, np.take_along_axis(t, np.maximum(n_valid - 1, 0)[..., None], -1)[..., 0],
                            previous)
        step_delta = np.maximum(grid[None, :] - last, 0.0)
    else:
        slot_delta = np.where(valid, np.maximum(grid[None, :, None] - t, 0.0), 0.0)
        step_delta = np.broadcast_to(grid - np.r_[grid[0], grid[:-1]], (n_reps, n_points))
    # only the deltas the loop reads (k >= 1; valid slots) enter the table
    used = np.concatenate([slot_delta[valid], step_delta[:, 1:].ravel()])
    rows, phi, drive, q = _tables(step, used)
    n_used = int(valid.sum())
    slot_key = np.zeros((n_reps, n_points, n_slots), np.int64)
    slot_key[valid] = rows[:n_used]
    step_key = np.zeros((n_reps, n_points), np.int64)
    step_key[:, 1:] = rows[n_used:].reshape(n_reps, n_points - 1)

    H = np.asarray(H, float)
    if sequential:
        n_sensors, m, n = H.shape
        h_eq = np.empty((0, n_sensors, 1, m, n))
        hgu = np.empty((0, n_sensors, 1, m))
        cross = np.empty((0, n_sensors, 1, n, m))
    else:
        # the reference's expressions on the table rows: H̄ = H Φ⁻¹, H̄ Γu, C = −Q H̄ᵀ
        h_eq = H[None, :, None] @ np.linalg.inv(phi)[:, None]  # (K, S, M, m, n)
        hgu = (h_eq @ drive[:, None, :, :, None])[..., 0]
        cross = -q[:, None] @ np.swapaxes(h_eq, -1, -2)
        h_eq, hgu, cross = (np.ascontiguousarray(a) for a in (h_eq, hgu, cross))

    n_models, n = phi.shape[1], phi.shape[2]
    x0 = np.broadcast_to(np.asarray(x0, float), (n_models, n))
    P0 = np.broadcast_to(np.asarray(P0, float), (n_models, n, n))
    out_mu = np.empty((n_reps, n_points, n_models))
    out_x = np.empty((n_reps, n_points, n_models, n))
    out_P = np.empty((n_reps, n_points, n_models, n, n))
    out_ll = np.empty((n_reps, n_points, n_models))
    fused_x = np.empty((n_reps, n_points, n))
    fused_P = np.empty((n_reps, n_points, n, n))
    status = np.zeros(n_reps, np.int8)
    args = (bool(sequential), counts.astype(np.int64), n_valid, y, np.ascontiguousarray(meas.sensor, np.int64),
            slot_key, step_key, np.ascontiguousarray(phi), np.ascontiguousarray(drive), np.ascontiguousarray(q),
            h_eq, hgu, cross, np.ascontiguousarray(H), np.ascontiguousarray(Rm, float),
            np.ascontiguousarray(trans, float), np.ascontiguousarray(mu0, float), np.ascontiguousarray(x0, float),
            np.ascontiguousarray(P0, float))
    outs = (out_mu, out_x, out_P, out_ll, fused_x, fused_P, status)
    _over_replications(lambda first, stop: imm(*args, first, stop, *outs), n_reps, threads)
    if status.any():
        return None
    return out_mu, out_x, out_P, out_ll, fused_x, fused_P


def warm_up() -> None:
    """Load (or compile) the kernel for both fusion forms."""
    n, m, n_models = 3, 2, 3

    class _Packets:
        t = np.array([[[np.nan], [0.5]]])
        y = np.zeros((1, 2, 1, m))
        sensor = np.zeros((1, 2, 1), np.int64)
        valid = np.array([[[False], [True]]])

    def step(delta):
        k = len(delta)
        return (np.broadcast_to(np.eye(n), (k, n_models, n, n)).copy(), np.zeros((k, n_models, n)),
                np.broadcast_to(np.eye(n), (k, n_models, n, n)).copy())

    H = np.zeros((1, m, n))
    H[0, :, :m] = np.eye(m)
    for sequential in (False, True):
        filter_batch(sequential, _Packets, np.arange(2.0), step, H, np.eye(m)[None], np.eye(n_models),
                     np.full(n_models, 1.0 / n_models), np.zeros(n), np.eye(n), threads=1)

"""The square-root cubature filter (:class:`mosd.estimators.CESCKF`, paper 000 eqs. 2–18), compiled.

One compiled call filters every replication over every step: per step it
draws the cubature points, pushes them through the plant's transition, forms
the weighted moments and takes the square roots with a Householder "tria" —
for 64 replications side by side (the innermost axis of every array, so the
compiler vectorises each line of the algebra) — the same algebra as the NumPy reference in
:mod:`mosd.estimators.cubature`, in the same layout (square roots carried
transposed, upper triangular, diagonal ≥ 0). Unlike the other kernels this
one is *not* bit-identical to its reference: the reference calls LAPACK's QR
on stacked matrices and BLAS for the products, whose order of additions a
loop does not reproduce; results agree to ~1e-13 relative
(``tests/test_kernels.py`` checks 1e-10 on states, covariances and
innovations over 5,000 steps, and that the tuned designs are unchanged).

Which models are compiled
-------------------------
The filter needs the plant's f and h as compiled code, and numba cannot cache
a function that receives another compiled function as an argument (every
process would recompile). So the transitions a kernel knows are listed here
by name (:data:`mosd.kernels.plants.TRANSITIONS`); a plant opts in by giving its
:class:`mosd.model.StateSpaceModel` a :class:`mosd.model.PointwiseModel`
(transition name, its parameters, and which states the outputs are). Any other
model takes the NumPy path. ``tests/test_kernels.py`` checks every compiled
transition against the plant's own NumPy ``f`` to 1e-14.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.core.errors import TypingError
from numba.extending import intrinsic

from . import configure_compiler

configure_compiler()  # before this module's first compile


from .plants import TRANSITIONS, _inner, transition, transition_lanes, transition_points  # noqa: F401  (re-exported)

# The filter's two big helpers are compiled once each, on their own, and CALLED through their address (an
# argument), not linked into their callers as numba links a compiled callee: numba copies a callee's module
# into every caller's and optimises and generates the copy again there, so _tria_lanes was compiled three
# times (its own, inside _update_lanes, inside cesckf) and _update_lanes twice, about 2.5 s of the cold
# cache's compile CPU. The argument types each is compiled for are fixed here; the call checks them.
_F1, _F2, _F3, _I = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1], types.int64
_TRIA_TYPES = (_F3, _I, _I, _F3, _I, _F1, _F1, _F1, _F1, _F1)
_UPDATE_TYPES = (_I, _I, _F3, _F3, _F2, _F2, _F2, _I, _F3, _F3, _F3, _F3, _F1, _F3, _F2, _F3, _F1, _F1, _F1, _F1, _F1,
                 _I)


def _call_at(expected):
    """An intrinsic ``call(address, arguments)``: the compiled function (numba's calling convention, no
    result) at ``address`` on the tuple ``arguments``, whose types must be ``expected``."""

    @intrinsic
    def call(typingctx, address, arguments):
        if not isinstance(address, types.Integer) or tuple(getattr(arguments, "types", ())) != expected:
            raise TypingError(f"a call by address takes {expected}, not {arguments}")

        def codegen(context, builder, signature, args):
            conv = context.call_conv
            function_type = conv.get_function_type(types.none, expected)
            callee = builder.inttoptr(args[0], function_type.as_pointer())
            status, _ = conv.call_function(builder, callee, types.none, expected,
                                           cgutils.unpack_tuple(builder, args[1], len(expected)))
            with cgutils.if_unlikely(builder, status.is_error):
                conv.return_status_propagate(builder, status)
            return context.get_dummy_value()

        return types.none(address, arguments), codegen

    return call


_call_tria = _call_at(_TRIA_TYPES)
_call_update = _call_at(_UPDATE_TYPES)
_ADDRESSES = {}


def _address(dispatcher, argument_types) -> int:
    """Where ``dispatcher``'s code for ``argument_types`` starts (compiled, or loaded from the cache, now)."""
    key = (dispatcher.py_func.__name__, argument_types)
    if key not in _ADDRESSES:
        dispatcher.compile(argument_types)
        compiled = dispatcher.overloads[argument_types]
        _ADDRESSES[key] = compiled.library.get_pointer_to_function(compiled.fndesc.llvm_func_name)
    return _ADDRESSES[key]


@_inner
def _tria_lanes(a, n_rows, n_cols, out, n_lanes, norm2, v0, vtv, alpha, scale):
    """Upper U (n_cols × n_cols), diag ≥ 0, with UᵀU = AᵀA, A = a[:n_rows, :n_cols], on every lane.

    The transposed "tria" of eqs. 10–11, 15, 18 by Householder QR on every lane of a (rows, cols,
    lanes) stack, lanes innermost (vectorised); ``a`` is overwritten. Diagonal signs are fixed so Uᵀ
    is the Cholesky factor (the reference's convention). A column with nothing below the diagonal to
    annihilate (or a zero column) gets a zero scale instead of a branch, so every lane runs the same
    operations.
    """
    for j in range(n_cols):
        for b in range(n_lanes):
            norm2[b] = 0.0
        for i in range(j, n_rows):
            for b in range(n_lanes):
                norm2[b] += a[i, j, b] * a[i, j, b]
        for b in range(n_lanes):
            ajj = a[j, j, b]
            norm = math.sqrt(norm2[b])
            alpha[b] = -norm if ajj >= 0.0 else norm
            v0[b] = ajj - alpha[b]
            vtv[b] = v0[b] * v0[b] + (norm2[b] - ajj * ajj)
        for c in range(j + 1, n_cols):
            for b in range(n_lanes):
                scale[b] = v0[b] * a[j, c, b]
            for i in range(j + 1, n_rows):
                for b in range(n_lanes):
                    scale[b] += a[i, j, b] * a[i, c, b]
            for b in range(n_lanes):
                scale[b] = 2.0 * scale[b] / vtv[b] if (norm2[b] > 0.0 and vtv[b] > 0.0) else 0.0
                a[j, c, b] -= scale[b] * v0[b]
            for i in range(j + 1, n_rows):
                for b in range(n_lanes):
                    a[i, c, b] -= scale[b] * a[i, j, b]
        for b in range(n_lanes):
            if norm2[b] > 0.0:
                a[j, j, b] = alpha[b]
            sign = -1.0 if a[j, j, b] < 0.0 else 1.0
            for c in range(n_cols):
                out[j, c, b] = sign * a[j, c, b] if c >= j else 0.0


@_inner
def _solve_columns(low, n, rhs, n_cols, out):
    """out[:n, :n_cols] = (L Lᵀ)⁻¹ rhs[:n, :n_cols] by a forward and a backward substitution.

    Used by :mod:`mosd.kernels.imm` (the filter here solves on its lanes in :func:`_update_lanes`).
    """
    for c in range(n_cols):
        for a in range(n):
            acc = rhs[a, c]
            for b in range(a):
                acc -= low[a, b] * out[b, c]
            out[a, c] = acc / low[a, a]
        for a in range(n - 1, -1, -1):
            acc = out[a, c]
            for b in range(a + 1, n):
                acc -= low[b, a] * out[b, c]
            out[a, c] = acc / low[a, a]


@_inner
def _update_lanes(n_ch, n_pts, centred_y, deviation, sr_t, xp, innov, nb, stack_y, syy, pxy, gain, acc, stack_yx,
                  xf, stf, norm2, v0, vtv, alpha, scale, tria):
    """Eqs. 12–18 for lanes 0..nb on the first ``n_ch`` channels of ``centred_y`` (N, eq. 17) and ``sr_t``.

    ``sr_t`` is S_Rᵀ restricted to those channels' columns (all of its rows: the rows of any square
    root of R are a square root of that block of R); ``innov`` the innovations r_k of those channels.
    Gives S_yyᵀ in ``syy``, x̂_{k|k} in ``xf`` and S_{k|k}ᵀ in ``stf``. The same code serves every lane
    with all channels and, one lane at a time, a lane with missing channels (their columns left out):
    one body to compile. ``tria``: the address of :func:`_tria_lanes` (called, not linked in).
    """
    n_x = deviation.shape[1]
    n_sr = sr_t.shape[0]
    # eq. 15: S_yy = tria([N, S_R])
    for i in range(n_pts):
        for c in range(n_ch):
            for b in range(nb):
                stack_y[i, c, b] = centred_y[i, c, b]
    _fill_rows(stack_y, n_pts, sr_t, nb)
    _call_tria(tria, (stack_y, n_pts + n_sr, n_ch, syy, nb, norm2, v0, vtv, alpha, scale))
    # eq. 14: P_xyᵀ = Nᵀ R; eq. 13: Kᵀ = S_yy⁻ᵀ (S_yy⁻¹ P_xyᵀ) by two triangular solves
    for a in range(n_ch):
        for j in range(n_x):
            for b in range(nb):
                acc[b] = 0.0
            for i in range(n_pts):
                for b in range(nb):
                    acc[b] += centred_y[i, a, b] * deviation[i, j, b]
            for b in range(nb):
                pxy[a, j, b] = acc[b]
    for j in range(n_x):
        for a in range(n_ch):  # forward: (S_yyᵀ)ᵀ z = P_xyᵀ, lower
            for b in range(nb):
                acc[b] = pxy[a, j, b]
            for c in range(a):
                for b in range(nb):
                    acc[b] -= syy[c, a, b] * gain[c, j, b]
            for b in range(nb):
                gain[a, j, b] = acc[b] / syy[a, a, b]
        for a in range(n_ch - 1, -1, -1):  # backward: S_yyᵀ Kᵀ = z, upper
            for b in range(nb):
                acc[b] = gain[a, j, b]
            for c in range(a + 1, n_ch):
                for b in range(nb):
                    acc[b] -= syy[a, c, b] * gain[c, j, b]
            for b in range(nb):
                gain[a, j, b] = acc[b] / syy[a, a, b]
    # eq. 12: x̂_{k|k} = x̂_{k|k−1} + K r_k
    for j in range(n_x):
        for b in range(nb):
            acc[b] = xp[j, b]
        for a in range(n_ch):
            for b in range(nb):
                acc[b] += innov[a, b] * gain[a, j, b]
        for b in range(nb):
            xf[j, b] = acc[b]
    # eq. 18: S_{k|k} = tria([R − K N, K S_R])
    for i in range(n_pts):
        for j in range(n_x):
            for b in range(nb):
                acc[b] = 0.0
            for a in range(n_ch):
                for b in range(nb):
                    acc[b] += centred_y[i, a, b] * gain[a, j, b]
            for b in range(nb):
                stack_yx[i, j, b] = deviation[i, j, b] - acc[b]
    for i in range(n_sr):
        for j in range(n_x):
            for b in range(nb):
                acc[b] = 0.0
            for a in range(n_ch):
                for b in range(nb):
                    acc[b] += sr_t[i, a] * gain[a, j, b]
            for b in range(nb):
                stack_yx[n_pts + i, j, b] = acc[b]
    _call_tria(tria, (stack_yx, n_pts + n_sr, n_x, stf, nb, norm2, v0, vtv, alpha, scale))


@_inner
def _store_lanes(first, k, n_lanes, x, root_t, x_out, root_out):
    """Step k of lanes 0..n_lanes into replications first..: x̂ and the lower root S (from Sᵀ, upper)."""
    n_x = x.shape[0]
    for b in range(n_lanes):
        for i in range(n_x):
            x_out[first + b, k, i] = x[i, b]
            for j in range(i + 1):
                root_out[first + b, k, i, j] = root_t[j, i, b]
            for j in range(i + 1, n_x):
                root_out[first + b, k, i, j] = 0.0


@_inner
def _fill_rows(stack, first_row, block, n_lanes):
    """stack[first_row + i, j, b] = block[i, j] for every lane: a square root shared by all replications."""
    for i in range(block.shape[0]):
        for j in range(block.shape[1]):
            for b in range(n_lanes):
                stack[first_row + i, j, b] = block[i, j]


#: The filter's steps, each a function of its own to read, inlined into :func:`cesckf` by numba (their IR, before
#: typing): one compiled body as when written in one piece, the same operations in the same order, no call and
#: no module of their own to compile (unlike the two big helpers above, each step is used once). Each is called
#: once per step and block of lanes, so the references numba counts for the arrays it receives cost little.
_lane_step = njit(inline="always", nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)


@_lane_step
def _workspace(n_pts, n_x, n_y, n_u, L):
    """The scratch arrays of one block of ``L`` lanes, and those of one lane with missing channels."""
    blocks = (np.empty((n_x, L)), np.empty((max(n_u, 1), L)), np.empty((n_pts, n_x, L)), np.empty((n_pts, n_x, L)),
              np.empty((n_pts, n_y, L)), np.empty((n_pts + n_x, n_x, L)), np.empty((n_y, L)))
    # [N; S_Rᵀ] (eq. 15), S_yyᵀ, P_xyᵀ, Kᵀ, [R − K N; K S_R]ᵀ (eq. 18) and the update's per-lane scratch
    update = (np.empty((n_pts + n_y, n_y, L)), np.empty((n_y, n_y, L)), np.empty((n_y, n_x, L)),
              np.empty((n_y, n_x, L)), np.empty(L), np.empty((n_pts + n_y, n_x, L)), np.empty(L), np.empty(L),
              np.empty(L), np.empty(L), np.empty(L))
    steps = (np.empty((n_x, L)), np.empty((n_x, n_x, L)), np.empty((n_x, L)), np.empty((n_x, n_x, L)),
             np.empty((n_y, L)))
    # one lane with missing channels, its present ones gathered into lane 0 (the rest reuses the scratch above)
    lane = (np.empty(n_y, np.int64), np.empty((n_pts, n_y, 1)), np.empty((n_pts, n_x, 1)), np.zeros((n_y, n_y)),
            np.empty((n_y, 1)), np.empty((n_x, 1)), np.empty((n_x, 1)), np.empty((n_x, n_x, 1)))
    return blocks, update, steps, lane


@_lane_step
def _start_lanes(nb, x0, st0, xp, stp):
    """x̂_{0|−1} = ``x0`` and S_{0|−1}ᵀ = ``st0`` on lanes 0..nb (a series' first sample)."""
    n_x = x0.shape[0]
    for i in range(n_x):
        for b in range(nb):
            xp[i, b] = x0[i]
        for j in range(n_x):
            for b in range(nb):
                stp[i, j, b] = st0[i, j]


@_lane_step
def _carry_in(nb, n_u, x_before, st_before, u_before, xf, stf, u_k):
    """A resumed series: x̂_{−1|−1}, S_{−1|−1}ᵀ and u_{−1}, the state a stream carries, on lanes 0..nb."""
    n_x = x_before.shape[0]
    for i in range(n_x):
        for b in range(nb):
            xf[i, b] = x_before[i]
        for j in range(n_x):
            for b in range(nb):
                stf[i, j, b] = st_before[i, j]
    for c in range(n_u):
        for b in range(nb):
            u_k[c, b] = u_before[c]


@_lane_step
def _predict_lanes(kind, params, nb, eps, weights, sqrt_w, sq_t, xf, stf, u_k, point, moved, stack_x, xp, stp, update,
                   tria):
    """x̂_{k|k−1} and S_{k|k−1}ᵀ from x̂_{k−1|k−1}, S_{k−1|k−1}ᵀ and u_{k−1} on lanes 0..nb (eqs. 3–5, 10–11).

    Eqs. 4–5: X_i = x̂ + S ε_i, X*_i = f(X_i, u_{k−1}); eq. 3: their weighted mean; eqs. 10–11:
    S_{k|k−1} = tria([M, S_Q]), M_i = √w_i (X*_i − x̂). ``update``: the update's scratch (its per-lane vectors
    serve the tria here).
    """
    n_pts, n_x = eps.shape
    norm2, v0, vtv, alpha, scale = update[6], update[7], update[8], update[9], update[10]
    for j in range(n_x):
        for b in range(nb):
            xp[j, b] = 0.0
    for i in range(n_pts):
        for j in range(n_x):
            for b in range(nb):
                point[j, b] = xf[j, b]
            for m in range(n_x):
                e = eps[i, m]
                for b in range(nb):
                    point[j, b] += e * stf[m, j, b]
        transition_lanes(kind, params, point, u_k, moved[i], nb)
        w = weights[i]
        for j in range(n_x):
            for b in range(nb):
                xp[j, b] += w * moved[i, j, b]
    for i in range(n_pts):
        s = sqrt_w[i]
        for j in range(n_x):
            for b in range(nb):
                stack_x[i, j, b] = s * (moved[i, j, b] - xp[j, b])
    _fill_rows(stack_x, n_pts, sq_t, nb)
    _call_tria(tria, (stack_x, n_pts + n_x, n_x, stp, nb, norm2, v0, vtv, alpha, scale))


@_lane_step
def _measurement_points(nb, eps, weights, sqrt_w, outputs, xp, stp, acc, point, deviation, centred_y, yp):
    """The points drawn from S_{k|k−1} and what the update needs of them, on lanes 0..nb.

    Eq. 8: X_i = x̂_{k|k−1} + S ε_i; eq. 16: ``deviation`` √w_i (X_i − x̂); eq. 9: Y_i = h(X_i) (the ``outputs``
    states); eq. 6: ŷ in ``yp``; eq. 17: ``centred_y`` N_i = √w_i (Y_i − ŷ).
    """
    n_pts, n_x = eps.shape
    n_y = outputs.shape[0]
    for c in range(n_y):
        for b in range(nb):
            yp[c, b] = 0.0
    for i in range(n_pts):
        s = sqrt_w[i]
        for j in range(n_x):
            for b in range(nb):
                acc[b] = 0.0
            for m in range(n_x):
                e = eps[i, m]
                for b in range(nb):
                    acc[b] += e * stp[m, j, b]
            for b in range(nb):
                deviation[i, j, b] = s * acc[b]
                point[j, b] = xp[j, b] + acc[b]
        w = weights[i]
        for c in range(n_y):
            o = outputs[c]
            for b in range(nb):
                centred_y[i, c, b] = point[o, b]
                yp[c, b] += w * point[o, b]
    for i in range(n_pts):
        s = sqrt_w[i]
        for c in range(n_y):
            for b in range(nb):
                centred_y[i, c, b] = s * (centred_y[i, c, b] - yp[c, b])


@_lane_step
def _store_innovations(r0, k, nb, yp, innov, syy, y_pred, innovation, innovation_cov):
    """Step k of lanes 0..nb into replications r0..: ŷ_{k|k−1}, r_k and S_yy S_yyᵀ over every channel."""
    n_y = yp.shape[0]
    for b in range(nb):
        for c in range(n_y):
            y_pred[r0 + b, k, c] = yp[c, b]
            innovation[r0 + b, k, c] = innov[c, b]
        for a in range(n_y):
            for c in range(n_y):
                total = 0.0
                for m in range(n_y):
                    total += syy[m, a, b] * syy[m, c, b]
                innovation_cov[r0 + b, k, a, c] = total


@_lane_step
def _missing_channels(r0, k, nb, y, yp, xp, stp, centred_y, deviation, sr_t, xf, stf, lane, update, tria, address):
    """Eqs. 12–18 again, on its present channels alone, for each of lanes 0..nb with a missing channel at step k.

    Through the same code (:func:`_update_lanes` at ``address``) with that lane's present columns gathered into
    lane 0 of the ``lane`` scratch; a lane with nothing present keeps the prediction.
    """
    n_pts, n_y, n_x = centred_y.shape[0], centred_y.shape[1], xp.shape[0]
    present, lane_centred_y, lane_deviation, lane_sr_t, lane_innov, lane_xp, lane_xf, lane_stf = lane
    stack_y, syy, pxy, gain, acc, stack_yx, norm2, v0, vtv, alpha, scale = update
    one = np.int64(1)
    for b in range(nb):
        # np.int64(0), not a bare 0 (here and for the 1 lane above): typing would first compile
        # _update_lanes and everything it calls for the literal value as well (twice the compile)
        n_present = np.int64(0)
        for c in range(n_y):
            if not math.isnan(y[r0 + b, k, c]):
                present[n_present] = c
                n_present += 1
        if n_present == n_y:
            continue
        if n_present == 0:
            for i in range(n_x):
                xf[i, b] = xp[i, b]
                for j in range(n_x):
                    stf[i, j, b] = stp[i, j, b]
            continue
        for i in range(n_pts):
            for a in range(n_present):
                lane_centred_y[i, a, 0] = centred_y[i, present[a], b]
            for j in range(n_x):
                lane_deviation[i, j, 0] = deviation[i, j, b]
        for i in range(n_y):
            for a in range(n_present):
                lane_sr_t[i, a] = sr_t[i, present[a]]
        for a in range(n_present):
            lane_innov[a, 0] = y[r0 + b, k, present[a]] - yp[present[a], b]
        for j in range(n_x):
            lane_xp[j, 0] = xp[j, b]
        _call_update(address, (n_present, n_pts, lane_centred_y, lane_deviation, lane_sr_t, lane_xp, lane_innov, one,
                               stack_y, syy, pxy, gain, acc, stack_yx, lane_xf, lane_stf, norm2, v0, vtv, alpha, scale,
                               tria))
        for i in range(n_x):
            xf[i, b] = lane_xf[i, 0]
            for j in range(n_x):
                stf[i, j, b] = lane_stf[i, j, 0]


#: replications filtered side by side (the innermost, vectorised axis of the kernel's arrays)
LANES = 64


@njit(cache=True, nogil=True, error_model="numpy")
def cesckf(kind, params, outputs, y, u, x0, st0, eps, weights, sq_t, sr_t, first, stop,
           x_pred, x_filt, sqrt_cov_pred, sqrt_cov_filt, y_pred, innovation, innovation_cov, lanes,
           resume, x_before, st_before, u_before, tria, update):
    """Filter replications ``first``..``stop`` (paper 000, eqs. 2–18); the compiled :meth:`CESCKF.filter`.

    Replications go ``lanes`` at a time, side by side: every array of the
    step carries them on its last axis, so each line of the algebra is a loop
    the compiler vectorises. A lane with a missing channel at a step has its
    update redone on the present channels (:func:`_update_lanes` on that lane alone).

    Parameters
    ----------
    kind : int
        The transition (:data:`TRANSITIONS`); ``params`` its parameters.
    outputs : int64 (n_y,)
        y_i = x[outputs[i]] (the measurement model h).
    y : float64 (R, N, n_y), NaN where a channel is missing
    u : float64 (R, N, n_u)
    x0 : float64 (n_x,); st0 : float64 (n_x, n_x)
        x̂_0 and S_0ᵀ.
    eps, weights : the unit cubature points (n_pts, n_x) and their weights (eq. 3).
    sq_t, sr_t : S_Qᵀ (n_x, n_x) and S_Rᵀ (n_y, n_y).
    first, stop : int
        The replications this call filters (threads share the output arrays).
    x_pred, x_filt : float64 (R, N, n_x), filled
        x̂_{k|k−1}, x̂_{k|k}.
    sqrt_cov_pred, sqrt_cov_filt : float64 (R, N, n_x, n_x), filled
        The lower square roots S_{k|k−1}, S_{k|k}.
    y_pred, innovation : float64 (R, N, n_y), filled
        ŷ_{k|k−1} and y_k − ŷ_{k|k−1} (NaN where y is).
    innovation_cov : float64 (R, N, n_y, n_y), filled
        S_yy S_yyᵀ over every channel.
    lanes : int
        Replications side by side.
    resume : bool
        False: y[:, 0] is the first sample (x̂_{0|−1} = ``x0``, S_{0|−1}ᵀ = ``st0``). True: the filter
        goes on from the step before y[:, 0] (a stream's next chunk, :class:`mosd.estimators.cubature.
        FilterStart`): x̂_{−1|−1} = ``x_before`` (n_x,), S_{−1|−1}ᵀ = ``st_before`` (n_x, n_x) and the input
        u_{−1} = ``u_before`` (n_u,) are predicted through eqs. 3–5, 10–11 like any other step, so a
        series filtered in chunks is bit for bit the series filtered in one call.
    tria, update : int
        Where :func:`_tria_lanes` and :func:`_update_lanes` start (:func:`_address`): called, not linked in.
    """
    n_steps, n_y, n_u = y.shape[1], y.shape[2], u.shape[2]
    sqrt_w = np.sqrt(weights)
    blocks, work, steps, lane = _workspace(weights.shape[0], x0.shape[0], n_y, n_u, lanes)
    point, u_k, moved, deviation, centred_y, stack_x, innov = blocks
    stack_y, syy, pxy, gain, acc, stack_yx, norm2, v0, vtv, alpha, scale = work
    xp, stp, xf, stf, yp = steps
    for r0 in range(first, stop, lanes):
        nb = min(lanes, stop - r0)
        for k in range(n_steps):
            if k == 0 and not resume:
                _start_lanes(nb, x0, st0, xp, stp)
            else:
                if k == 0:  # resumed: the step before this call's first sample is the carried state
                    _carry_in(nb, n_u, x_before, st_before, u_before, xf, stf, u_k)
                else:
                    for c in range(n_u):
                        for b in range(nb):
                            u_k[c, b] = u[r0 + b, k - 1, c]
                _predict_lanes(kind, params, nb, eps, weights, sqrt_w, sq_t, xf, stf, u_k, point, moved, stack_x, xp,
                               stp, work, tria)
            _store_lanes(r0, k, nb, xp, stp, x_pred, sqrt_cov_pred)
            _measurement_points(nb, eps, weights, sqrt_w, outputs, xp, stp, acc, point, deviation, centred_y, yp)
            for c in range(n_y):
                for b in range(nb):
                    innov[c, b] = y[r0 + b, k, c] - yp[c, b]
            # eqs. 12–18 over every channel, then again on the present ones of a lane with a missing channel
            _call_update(update, (n_y, weights.shape[0], centred_y, deviation, sr_t, xp, innov, nb, stack_y, syy, pxy,
                                  gain, acc, stack_yx, xf, stf, norm2, v0, vtv, alpha, scale, tria))
            _store_innovations(r0, k, nb, yp, innov, syy, y_pred, innovation, innovation_cov)
            _missing_channels(r0, k, nb, y, yp, xp, stp, centred_y, deviation, sr_t, xf, stf, lane, work, tria,
                              update)
            _store_lanes(r0, k, nb, xf, stf, x_filt, sqrt_cov_filt)


def filter_batch(kind, params, outputs, y, u, x0, st0, eps, weights, sq_t, sr_t, threads=None, lanes=LANES,
                 start=None):
    """:func:`cesckf` over every replication of ``y`` (R, N, n_y), split over ``threads`` threads.

    ``start``: None (the first sample is y[:, 0]) or (x̂, Sᵀ, u) of the step before it, shared by every
    replication (:func:`cesckf`'s ``resume``).

    Replications are independent, so neither the split over threads nor
    ``lanes`` (replications side by side in the kernel) changes a number; the
    kernel releases the GIL, so threads run it in parallel. ``threads=None`` uses
    :func:`mosd.kernels.threads`.

    Returns
    -------
    x_pred, x_filt, sqrt_cov_pred, sqrt_cov_filt, y_pred, innovation, innovation_cov
    """
    from . import threads as default_threads

    n_reps, n_steps, n_y = y.shape
    n_x = x0.shape[0]
    outs = (np.empty((n_reps, n_steps, n_x)), np.empty((n_reps, n_steps, n_x)),
            np.empty((n_reps, n_steps, n_x, n_x)), np.empty((n_reps, n_steps, n_x, n_x)),
            np.empty((n_reps, n_steps, n_y)), np.empty((n_reps, n_steps, n_y)), np.empty((n_reps, n_steps, n_y, n_y)))
    if start is None:
        resume, before = False, (x0, st0, np.zeros(u.shape[2]))
    else:
        resume, before = True, tuple(np.ascontiguousarray(a, dtype=np.float64) for a in start)
    sr_t = np.array(sr_t, dtype=np.float64, order="C")  # a writable C array: the type _update_lanes is compiled for
    if len(_ADDRESSES) < 2:
        # This process's first filter: cesckf's own code is loaded or compiled first, on no replication (its
        # helpers are not called), and the helpers' after it: a second process may be compiling the helpers
        # meanwhile (mosd.kernels.ahead), which then costs this one no wait.
        cesckf(kind, params, outputs, y, u, x0, st0, eps, weights, sq_t, sr_t, 0, 0, *outs, lanes, resume, *before,
               0, 0)
    helpers = (_address(_tria_lanes, _TRIA_TYPES), _address(_update_lanes, _UPDATE_TYPES))
    _over_replications(lambda first, stop: cesckf(kind, params, outputs, y, u, x0, st0, eps, weights, sq_t, sr_t,
                                                   first, stop, *outs, lanes, resume, *before, *helpers), n_reps,
                       threads)
    return outs


def helper_dispatchers() -> tuple:
    """The filter's helpers that :func:`cesckf` calls by address (what :mod:`mosd.kernels.ahead` can compile apart)."""
    return _tria_lanes, _update_lanes


def warm_up_helpers() -> None:
    """Load (or compile) the filter's helpers alone, for the types :func:`cesckf` calls them with."""
    _address(_tria_lanes, _TRIA_TYPES)
    _address(_update_lanes, _UPDATE_TYPES)


def _over_replications(run, n_reps, threads=None):
    """run(first, stop) over [0, n_reps) split into contiguous blocks, one per thread."""
    from . import threads as default_threads

    n_threads = max(1, min(default_threads() if threads is None else int(threads), n_reps))
    if n_threads == 1:
        run(0, n_reps)
        return
    from concurrent.futures import ThreadPoolExecutor

    bounds = np.linspace(0, n_reps, n_threads + 1).astype(np.int64)
    with ThreadPoolExecutor(n_threads) as pool:
        for future in [pool.submit(run, bounds[i], bounds[i + 1]) for i in range(n_threads)]:
            future.result()


@njit(cache=True, nogil=True, error_model="numpy")
def _output_prediction(x_pred, sqrt_cov_pred, eps, weights, outputs, meas_cov, first, stop, y_pred, cov):
    n_steps, n_x = x_pred.shape[1], x_pred.shape[2]
    n_pts, n_y = weights.shape[0], outputs.shape[0]
    sqrt_w = np.sqrt(weights)
    predicted = np.empty((n_pts, n_y))
    yp = np.empty(n_y)
    for r in range(first, stop):
        for k in range(n_steps):
            for i in range(n_pts):
                for c in range(n_y):
                    j = outputs[c]
                    acc = 0.0
                    for m in range(n_x):
                        acc += sqrt_cov_pred[r, k, j, m] * eps[i, m]
                    predicted[i, c] = x_pred[r, k, j] + acc
            for c in range(n_y):
                acc = 0.0
                for i in range(n_pts):
                    acc += weights[i] * predicted[i, c]
                yp[c] = acc
                y_pred[r, k, c] = acc
            for i in range(n_pts):
                for c in range(n_y):
                    predicted[i, c] = sqrt_w[i] * (predicted[i, c] - yp[c])
            for a in range(n_y):
                for b in range(n_y):
                    acc = 0.0
                    for i in range(n_pts):
                        acc += predicted[i, a] * predicted[i, b]
                    cov[r, k, a, b] = acc + meas_cov[a, b]


def output_prediction(x_pred, sqrt_cov_pred, eps, weights, outputs, meas_cov, threads=None):
    """ŷ_{k|k−1} and its covariance for the outputs ``outputs`` (states) from stored predictions (eqs. 6, 8, 15).

    The compiled :func:`mosd.estimators.residuals._output_prediction`: the
    points x̂ + S ε_i of every stored S_{k|k−1} (lower), their weighted mean and
    Σ √w_i² (Y_i − ŷ)(Y_i − ŷ)ᵀ + R.
    """
    n_reps, n_steps, _ = x_pred.shape
    n_y = len(outputs)
    y_pred = np.empty((n_reps, n_steps, n_y))
    cov = np.empty((n_reps, n_steps, n_y, n_y))
    args = (np.ascontiguousarray(x_pred), np.ascontiguousarray(sqrt_cov_pred), np.ascontiguousarray(eps),
            np.asarray(weights, float), np.asarray(outputs, np.int64), np.ascontiguousarray(meas_cov, float))
    _over_replications(lambda first, stop: _output_prediction(*args, first, stop, y_pred, cov), n_reps, threads)
    return y_pred, cov


def warm_up() -> None:
    """Load (or compile) the filter for the mould oscillator's shapes."""
    n_x = 3
    filter_batch(0, np.ones(8), np.arange(n_x), np.zeros((1, 2, n_x)), np.zeros((1, 2, 1)), np.zeros(n_x),
                 np.eye(n_x), np.zeros((1, n_x)), np.ones(1), np.eye(n_x), np.eye(n_x), threads=1)
    output_prediction(np.zeros((1, 2, n_x)), np.zeros((1, 2, n_x, n_x)), np.zeros((1, n_x)), np.ones(1),
                      np.arange(n_x), np.eye(n_x), threads=1)

"""The MOPSO move, compiled: :func:`particle_move` and :func:`offspring`.

One move of :class:`mosd.optim.mopso.MOPSO` (eqs. 38–39, SMPSO's constricted move for the exploring
particles, the bounds, pymoo's polynomial mutation, and the archive offspring's SBX and polynomial mutation)
was about a hundred small NumPy calls on arrays of a few hundred numbers: 0.8–1.5 ms of the optimiser's
own time per generation on two cores, where Amdahl's law caps the speed-up of every parallel evaluation
(issue 32). Here each of the two parts is one call.

The draws are the NumPy code's, in its order, from the optimiser's own :class:`numpy.random.Generator`:
the kernels call its bit generator's C functions (``next_double``, ``next_uint32``, through the addresses
NumPy publishes in ``BitGenerator.ctypes``) on its state, as the Generator's methods do: ``random`` is one
``next_double`` per number, ``uniform(low, high)`` is ``low + (high − low) · next_double``, and
``integers(2)`` is Lemire's bounded draw on ``next_uint32`` (whose spare half-word the bit generator keeps
in its state, so the next call sees it as NumPy's would). numba's own Generator support gives the same
numbers but links its whole implementation into each kernel: 0.46 MB of code, 13 s to compile on an empty
cache and 35–50 ms to load from it, as much as the kernels save in a run of the main command. The
Generator's lock is not taken: the optimiser's generator is used by one thread.

The arithmetic is the NumPy code's, expression for expression on the same elements (numba compiles without
fast-math: nothing is reassociated or fused), so the positions are the same bits where NumPy's ``power`` is
the C library's ``pow``, as on every machine without AVX-512 (there NumPy may take a SIMD ``pow`` that
rounds some results to the neighbouring float). ``tests/test_kernel_swarm.py`` compares the two paths on random
swarms, the generator's state after them included.
"""
from __future__ import annotations

import ctypes
import functools
import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from . import configure_compiler

configure_compiler()  # before this module's first compile

#: a helper called only from compiled code: no CPython or C-callable entry point to generate and compile
_inner = njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)

#: boundary rules of :func:`mosd.optim.mopso.apply_bounds`, as the kernel's codes
BOUNDARY_CODES = {"clip": 0, "reflect": 1, "absorb": 2}


def _bit_function(result_type):
    """An intrinsic ``draw(function_address, state_address)``: a bit generator's C function on its state."""

    @intrinsic
    def draw(typingctx, function_address, state_address):
        def codegen(context, builder, signature, args):
            void_pointer = ir.IntType(8).as_pointer()
            function_type = ir.FunctionType(context.get_value_type(result_type), [void_pointer])
            function = builder.inttoptr(args[0], function_type.as_pointer())
            return builder.call(function, [builder.inttoptr(args[1], void_pointer)])

        return result_type(types.intp, types.intp), codegen

    return draw


_next_double = _bit_function(types.float64)
_next_uint32 = _bit_function(types.uint32)


def bit_source(generator: np.random.Generator) -> np.ndarray:
    """The addresses the kernels draw with: ``[next_double, next_uint32, state]`` of ``generator``'s bit generator.

    Valid while ``generator`` lives; NumPy keeps its ctypes interface once built, so this is cheap after the
    first call.
    """
    interface = generator.bit_generator.ctypes
    return np.array([ctypes.cast(interface.next_double, ctypes.c_void_p).value,
                     ctypes.cast(interface.next_uint32, ctypes.c_void_p).value, interface.state_address],
                    dtype=np.intp)


@_inner
def _clip(value, low, high):
    # np.clip's scalar rule: a NaN stays, max first, then min
    if np.isnan(value):
        return value
    value = value if value > low else low
    if np.isnan(value):
        return value
    return value if value < high else high


@_inner
def _polynomial_mutation(X, xl, xu, etas, per_variable, share, source):
    """:func:`mosd.optim.mopso.polynomial_mutation` (``per_variable`` = 1/n_var) with one distribution index per
    row, ``etas[i]``, on ``X`` in place: :func:`mosd.optim.mopso.polynomial_steps`' draws and arithmetic."""
    n, n_var = X.shape
    # polynomial_steps: one uniform per variable (mutated below per_variable; never a fixed variable) ...
    mutate = np.empty((n, n_var), dtype=np.bool_)
    for i in range(n):
        for j in range(n_var):
            mutate[i, j] = _next_double(source[0], source[2]) < per_variable and xl[j] != xu[j]
    # ... then one per mutated variable, in row-major order (X[mutate]'s)
    steps = np.empty((n, n_var))
    for i in range(n):
        for j in range(n_var):
            if not mutate[i, j]:
                steps[i, j] = X[i, j]
                continue
            x, low, high = X[i, j], xl[j], xu[j]
            r = _next_double(source[0], source[2])
            exponent = etas[i] + 1.0
            delta1 = (x - low) / (high - low)
            delta2 = (high - x) / (high - low)
            power = 1.0 / exponent
            if r <= 0.5:
                val = 2.0 * r + (1.0 - 2.0 * r) * ((1.0 - delta1) ** exponent)
                step = val ** power - 1.0
            else:
                val = 2.0 * (1.0 - r) + 2.0 * (r - 0.5) * ((1.0 - delta2) ** exponent)
                step = 1.0 - val ** power
            y = x + step * (high - low)
            steps[i, j] = high if y > high else (low if y < low else y)
    # the mutated rows replace a row where a uniform draw is <= share
    for i in range(n):
        if _next_double(source[0], source[2]) <= share:
            for j in range(n_var):
                y = steps[i, j]
                if y < xl[j]:
                    y = xl[j]
                if y > xu[j]:
                    y = xu[j]
                X[i, j] = y
    return X


@njit(cache=True, nogil=True, error_model="numpy")
def particle_move(X, previous_velocity, personal, leaders, w, c1, c2, limit, n_exploring, smpso_low, smpso_high,
                  smpso_inertia, smpso_max_velocity, xl, xu, boundary, mutate, etas, mutation_rate, source):
    """The particles' part of :meth:`mosd.optim.mopso.MOPSO._moved_positions`: new positions and velocities.

    Eq. 39's velocity w v + c1 r1 (pbest − x) + c2 r2 (leader − x), clamped to ±``limit`` (no clamp when
    ``limit`` is empty); SMPSO's move (:func:`mosd.optim.mopso.smpso_velocity`) for the first ``n_exploring``
    particles; eq. 38's move with the boundary rule (:func:`mosd.optim.mopso.apply_bounds`: ``boundary`` 0
    clip, 1 reflect, 2 absorb); then, when ``mutate``, pymoo's polynomial mutation of a share
    ``mutation_rate`` of the particles (:func:`mosd.optim.mopso.polynomial_mutation`, index ``etas[i]`` for
    row i). ``source``: :func:`bit_source` of the optimiser's generator.

    Returns
    -------
    positions, velocity : ndarray, shape (n, n_var)
    """
    n, n_var = X.shape
    velocity = np.empty((n, n_var))
    for i in range(n):  # r1 for every particle and variable, then r2
        for j in range(n_var):
            velocity[i, j] = c1 * _next_double(source[0], source[2]) * (personal[i, j] - X[i, j])
    for i in range(n):
        for j in range(n_var):
            v = (w * previous_velocity[i, j] + velocity[i, j]
                 + c2 * _next_double(source[0], source[2]) * (leaders[i, j] - X[i, j]))
            if limit.size:
                v = _clip(v, -limit[j], limit[j])
            velocity[i, j] = v
    if n_exploring > 0:
        # uniform(low, high, size=(2, n, 1)) = low + (high - low) * next_double: c1 of every exploring particle,
        # then c2; then random((2, n, 1)): r1, then r2
        draws = np.empty(4 * n_exploring)
        for m in range(4 * n_exploring):
            u = _next_double(source[0], source[2])
            draws[m] = smpso_low + (smpso_high - smpso_low) * u if m < 2 * n_exploring else u
        for i in range(n_exploring):
            a, b = draws[i], draws[n_exploring + i]
            s, t = draws[2 * n_exploring + i], draws[3 * n_exploring + i]
            phi = a + b
            chi = 1.0
            if phi > 4.0:
                chi = 2.0 / (2.0 - phi - np.sqrt(max(phi * phi - 4.0 * phi, 0.0)))
            for j in range(n_var):
                x = X[i, j]
                v = chi * (smpso_inertia * previous_velocity[i, j] + a * s * (personal[i, j] - x)
                           + b * t * (leaders[i, j] - x))
                bound = smpso_max_velocity * (xu[j] - xl[j])
                velocity[i, j] = _clip(v, -bound, bound)
    positions = np.empty((n, n_var))
    for i in range(n):
        for j in range(n_var):
            x = X[i, j] + velocity[i, j]
            if x < xl[j] or x > xu[j]:
                if boundary == 1:
                    velocity[i, j] = -velocity[i, j]
                elif boundary == 2:
                    velocity[i, j] = 0.0
            if x < xl[j]:
                x = xl[j]
            if x > xu[j]:
                x = xu[j]
            positions[i, j] = x
    if mutate:
        _polynomial_mutation(positions, xl, xu, etas, 1.0 / n_var, mutation_rate, source)
    return positions, velocity


@_inner
def _spread(beta, r, exponent, root):
    alpha = 2.0 - beta ** exponent
    threshold, scaled = 1.0 / alpha, r * alpha
    if r <= threshold:
        return scaled ** root
    if r > threshold:
        return (1.0 / (2.0 - scaled)) ** root
    return 0.0  # pymoo leaves 0 where neither comparison holds (1 / alpha NaN)


@njit(cache=True, nogil=True, error_model="numpy")
def offspring(first, second, xl, xu, probability, eta, etas, source):
    """:meth:`mosd.optim.mopso.MOPSO._varied_children` after the parents' choice: SBX, then polynomial mutation.

    One child per pair of :func:`mosd.optim.mopso.sbx_children` (pymoo's ``SBX(prob=probability, eta=eta,
    n_offsprings=1)``, its pairs by :func:`mosd.optim.mopso.sbx_pairs`), then
    :func:`mosd.optim.mopso.polynomial_mutation` of every child (index ``etas[i]`` for child i); the draws from
    ``source`` (:func:`bit_source`).
    """
    n, n_var = first.shape
    children = np.empty((n, n_var))
    cross = np.empty(n, dtype=np.bool_)
    n_crossing = 0
    for i in range(n):
        cross[i] = _next_double(source[0], source[2]) < probability
        n_crossing += cross[i]
    if n_crossing:
        for i in range(n):  # SBX._do's draw against prob_exch = 1: never disables a pair
            _next_double(source[0], source[2])
        # sbx_pairs: one uniform per variable and pair (crossed below 0.5, not where the parents are within
        # 1e-14 or the variable is fixed), then the spreads and the exchanges, one each per crossed variable
        crossed = np.empty((n, n_var), dtype=np.bool_)
        k = 0
        for i in range(n):
            for j in range(n_var):
                crossed[i, j] = (_next_double(source[0], source[2]) < 0.5
                                 and not abs(first[i, j] - second[i, j]) <= 1.0e-14 and xl[j] != xu[j])
                k += crossed[i, j]
        draws = np.empty(2 * k)
        for m in range(2 * k):
            draws[m] = _next_double(source[0], source[2])
        exponent, root = -(eta + 1.0), 1.0 / (eta + 1.0)
        pairs = np.empty((2, n, n_var))
        m = 0
        for i in range(n):
            for j in range(n_var):
                p1, p2 = first[i, j], second[i, j]
                if crossed[i, j]:
                    r, exchange_draw = draws[m], draws[k + m]
                    m += 1
                    smaller = p1 < p2
                    y1 = p1 if smaller else p2
                    y2 = p2 if smaller else p1
                    low, high = xl[j], xu[j]
                    delta = y2 - y1
                    c1 = 0.5 * ((y1 + y2) - _spread(1.0 + (2.0 * (y1 - low) / delta), r, exponent, root) * delta)
                    c2 = 0.5 * ((y1 + y2) + _spread(1.0 + (2.0 * (high - y2) / delta), r, exponent, root) * delta)
                    child1 = c1 if smaller else c2
                    child2 = c2 if smaller else c1
                    if (exchange_draw < 0.5) != (p1 > p2):
                        p1, p2 = child2, child1
                    else:
                        p1, p2 = child1, child2
                pairs[0, i, j], pairs[1, i, j] = p1, p2
        for i in range(n):
            take_second = _next_double(source[0], source[2]) < 0.5
            if cross[i]:
                for j in range(n_var):
                    value = pairs[1, i, j] if take_second else pairs[0, i, j]
                    if value < xl[j]:
                        value = xl[j]
                    if value > xu[j]:
                        value = xu[j]
                    children[i, j] = value
    # a pair that does not cross copies one parent: the operator's one bounded draw per such pair, Lemire's
    # on a 32-bit word with range 1 (whose rejection threshold (2**32 - 2) % 2 is 0: no word is rejected)
    for i in range(n):
        if not cross[i]:
            word = np.uint64(_next_uint32(source[1], source[2]))
            parent = second if (word * np.uint64(2)) >> np.uint64(32) == 1 else first
            for j in range(n_var):
                children[i, j] = parent[i, j]
    return _polynomial_mutation(children, xl, xu, etas, 1.0 / n_var, 1.0, source)


@functools.lru_cache(maxsize=None)
def matches_numpy() -> bool:
    """Whether NumPy's ``power`` is the C library's ``pow`` here (checked once on 512 values): then the kernels give
    the NumPy move's bits, and a run may take either move at any generation with the same result."""
    rng = np.random.default_rng(0)
    base, exponent = rng.uniform(0.0, 2.0, 512), rng.uniform(-30.0, 30.0, 512)
    return bool(np.array_equal(np.power(base, exponent), [math.pow(a, b) for a, b in zip(base, exponent)]))


def ready() -> bool:
    """Whether a move should run compiled now: its code is loaded here, or nobody else is compiling it (then it is
    loaded from numba's cache, or compiled here, as any kernel where a run first calls it).

    While the second process of :mod:`mosd.kernels.ahead` compiles it (about 5 s on an empty cache, after the
    run's other kernels) the optimiser takes the NumPy move instead of waiting, which gives the same numbers
    where :func:`matches_numpy`; elsewhere it waits, so that a run's positions never depend on when a
    compilation ended.
    """
    if particle_move.overloads and offspring.overloads:
        return True
    from . import ahead

    return not ahead.pending("swarm") or not matches_numpy()


def warm_up() -> None:
    """Load (or compile) both kernels on a two-variable swarm (what every MOPSO run calls)."""
    generator = np.random.default_rng(0)  # alive while its state is drawn from
    source = bit_source(generator)
    X = np.zeros((2, 2))
    bounds = np.zeros(2), np.ones(2)
    # one signature serves every configuration (no clamp is an empty limit, no mutation a flag)
    particle_move(X, X, X, X, 0.5, 1.0, 1.0, np.ones(2), 1, 1.5, 2.5, 0.1, 0.5, *bounds, 0, True, np.ones(2),
                  0.5, source)
    offspring(X, X + 0.5, *bounds, 0.9, 15.0, np.ones(2), source)

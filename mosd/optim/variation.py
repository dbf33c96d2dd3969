"""The swarm's moves and variation operators on arrays (paper 000, §2.2.2; :class:`mosd.optim.mopso.MOPSO`).

Functions of positions, velocities and bounds that draw from the Generator they are given and keep no state:
the constriction coefficients (paper 000, below eq. 39), SMPSO's constricted move, the boundary rules, Deb's
polynomial mutation and simulated binary crossover written on arrays with pymoo's arithmetic and draws (issue 32),
the uniform redraw of one variable (issue 33) and the rounding of integer variables. The compiled move
(:mod:`mosd.kernels.swarm`) does the same arithmetic in one call; ``tests/test_kernel_swarm.py`` compares the two.
"""
from __future__ import annotations

import math

import numpy as np

from ..validation import ConfigError, Interval, check_in

#: φ = φ1 + φ2 of Clerc & Kennedy's constriction factor; paper 000 (below eq. 39) uses 4.1.
CONSTRICTION_PHI = 4.1
#: Ways to treat a particle that leaves the box, see :func:`apply_bounds`.
BOUNDARY_RULES = ("clip", "reflect", "absorb")
#: SMPSO's move (Nebro et al. 2009): c1, c2 ~ U[1.5, 2.5] per particle and move, inertia 0.1,
#: velocity clamp ±0.5 (xu − xl); see :func:`smpso_velocity`.
SMPSO_C_RANGE = (1.5, 2.5)
SMPSO_INERTIA = 0.1
SMPSO_MAX_VELOCITY = 0.5
#: The archive offspring's simulated binary crossover (see :meth:`MOPSO._archive_offspring`): pymoo's
#: defaults, which are its NSGA-II's (probability 0.9 per pair, η = 15, each variable with probability 0.5).
CROSSOVER_PROBABILITY = 0.9
CROSSOVER_ETA = 15.0


def constriction_coefficients(phi: float = CONSTRICTION_PHI) -> tuple[float, float, float]:
    """Constriction factor and acceleration coefficients (paper 000, text below eq. 39).

    w = 2 / (φ − 2 + √(φ² − 4φ)), c1 = w φ1, c2 = w φ2 with φ1 = φ2 = φ / 2.
    φ = 4.1 gives w = 0.7298 and c1 = c2 = 1.4962 (Table 2).

    Parameters
    ----------
    phi : float
        φ > 4.

    Returns
    -------
    w, c1, c2 : float
    """
    phi = check_in("optimizer.phi", phi, Interval(4.0, math.inf, open_low=True))
    w = 2.0 / (phi - 2.0 + math.sqrt(phi * phi - 4.0 * phi))
    return w, w * phi / 2.0, w * phi / 2.0


def smpso_velocity(X: np.ndarray, V: np.ndarray, personal: np.ndarray, leaders: np.ndarray,
                   xl: np.ndarray, xu: np.ndarray, random_state: np.random.Generator) -> np.ndarray:
    """SMPSO's constricted velocity (Nebro et al., MCDM 2009, eqs. 2–4), as published and as jMetal runs it.

    v ← χ (0.1 v + c1 r1 (pbest − x) + c2 r2 (leader − x)), clamped to ±(xu − xl)/2 per
    variable, with c1, c2 ~ U[1.5, 2.5] and r1, r2 ~ U(0, 1) drawn once per particle
    (jMetal), φ = c1 + c2 and χ = 2 / (2 − φ − √(φ² − 4φ)) for φ > 4, else 1.

    The published χ has no absolute value (Clerc's has): for φ > 4, half of the draws,
    it is negative (−1 … −0.38), so about half the moves go *away* from pbest and the
    leader by up to their distance. That is what keeps the swarm spread on Rastrigin-type
    landscapes (docs/MOPSO.md, "Multimodal problems"): with Clerc's positive χ the same
    rule collapses on ZDT4 like the attraction-only default did. Because the steps scale
    with the distance to the attractors, they shrink as pbest and leaders converge.

    Parameters
    ----------
    X, V, personal, leaders : ndarray, shape (n, n_var)
        Positions, velocities, personal bests and each particle's leader.
    xl, xu : ndarray, shape (n_var,)
    random_state : numpy.random.Generator

    Returns
    -------
    ndarray, shape (n, n_var)
    """
    n = len(X)
    c1, c2 = random_state.uniform(*SMPSO_C_RANGE, size=(2, n, 1))
    r1, r2 = random_state.random((2, n, 1))
    phi = c1 + c2
    chi = np.where(phi > 4.0, 2.0 / (2.0 - phi - np.sqrt(np.maximum(phi * phi - 4.0 * phi, 0.0))), 1.0)
    velocity = chi * (SMPSO_INERTIA * V + c1 * r1 * (personal - X) + c2 * r2 * (leaders - X))
    limit = SMPSO_MAX_VELOCITY * (xu - xl)
    return np.clip(velocity, -limit, limit)


def apply_bounds(X: np.ndarray, V: np.ndarray, xl: np.ndarray, xu: np.ndarray,
                 rule: str = "reflect") -> tuple[np.ndarray, np.ndarray]:
    """Bring positions that left the box back to its bound and adjust their velocity.

    Every rule sets an out-of-range coordinate to the bound it crossed; they differ in
    what happens to that velocity component:

    * ``"clip"`` — it is kept, so a particle still pushed outwards stays on the bound
      (what pymoo's PSO-type repairs do to positions). The default: measured, it is the
      rule that lets the swarm settle on optima at a bound (ZDT) while it costs nothing
      when the optimum is inside the box (shifted ZDT1, DTLZ2), see ``docs/MOPSO.md``.
    * ``"reflect"`` — its sign is reversed: paper 000 (text after eq. 39) and Coello
      2004 §IV-B; SMPSO does the same.
    * ``"absorb"`` — it is set to 0 ("absorbing walls", Robinson & Rahmat-Samii,
      IEEE Trans. Antennas Propag. 52(2), 2004).

    Parameters
    ----------
    X, V : ndarray, shape (n, n_var)
        Positions after eq. 38 and the velocities that produced them.
    xl, xu : ndarray, shape (n_var,)
        Bounds.
    rule : {"clip", "reflect", "absorb"}

    Returns
    -------
    X, V : ndarray
        New arrays; X within [xl, xu].
    """
    outside = (X < xl) | (X > xu)
    if rule == "reflect":
        V = np.where(outside, -V, V)
    elif rule == "absorb":
        V = np.where(outside, 0.0, V)
    elif rule != "clip":
        raise ConfigError(f"optimizer.boundary={rule!r} is not allowed; allowed: {', '.join(BOUNDARY_RULES)}")
    return to_bounds(np.array(X, dtype=float), xl, xu), V


def to_bounds(X: np.ndarray, xl, xu) -> np.ndarray:
    """X with coordinates below ``xl`` set to it, then those above ``xu`` set to that, in place (returned).

    pymoo's ``set_to_bounds_if_outside`` and ``repair_clamp`` (lower bound first, then upper; a NaN stays):
    the same values, without building (n, n_var) copies of the bounds.
    """
    np.copyto(X, xl, where=X < xl)
    np.copyto(X, xu, where=X > xu)
    return X


def polynomial_steps(X: np.ndarray, xl: np.ndarray, xu: np.ndarray, etas: np.ndarray, prob: float,
                     random_state: np.random.Generator) -> np.ndarray:
    """Deb's polynomial mutation of each variable with probability ``prob``: pymoo's ``mut_pm``, on arrays.

    The same arithmetic as ``mut_pm(X, xl, xu, etas, np.full(n, prob), at_least_once=False)`` of pymoo
    0.6, expression for expression on the same elements (so the same floats), and its draws in its order:
    one uniform per variable and row (mutated when below ``prob``), then one per mutated variable; variables
    with ``xl == xu`` are never mutated. pymoo's function builds (n, n_var) copies of the bounds and of the
    indices and indexes them with the mask about thirty times, which on a swarm of 100 cost more than the
    mutation (issue 32); ``tests/test_mopso_serial.py`` compares the two on random inputs.

    Parameters
    ----------
    X : ndarray, shape (n, n_var)
    xl, xu : ndarray, shape (n_var,)
    etas : ndarray, shape (n,)
        Distribution index per row.
    prob : float
        Probability per variable.
    random_state : numpy.random.Generator

    Returns
    -------
    ndarray, shape (n, n_var)
        A new array.
    """
    n, n_var = X.shape
    mutate = random_state.random((n, n_var)) < prob
    fixed = xl == xu
    if fixed.any():
        mutate[:, fixed] = False
    out = np.array(X, dtype=float)
    rows, columns = np.nonzero(mutate)  # row-major: the order of X[mutate]
    x, low, high = out[rows, columns], xl[columns], xu[columns]
    exponent = etas[rows] + 1.0
    delta1 = (x - low) / (high - low)
    delta2 = (high - x) / (high - low)
    power = 1.0 / exponent
    rand = random_state.random(x.shape)
    with np.errstate(invalid="ignore"):
        val = 2.0 * rand + (1.0 - 2.0 * rand) * (np.power(1.0 - delta1, exponent))
        below = np.power(val, power) - 1.0
        val = 2.0 * (1.0 - rand) + 2.0 * (rand - 0.5) * (np.power(1.0 - delta2, exponent))
        above = 1.0 - (np.power(val, power))
    y = x + np.where(rand <= 0.5, below, above) * (high - low)
    out[rows, columns] = to_bounds(y, low, high)
    return to_bounds(out, xl, xu)


def polynomial_mutation(X: np.ndarray, xl: np.ndarray, xu: np.ndarray, eta, share: float,
                        random_state: np.random.Generator) -> np.ndarray:
    """pymoo's ``PolynomialMutation(prob=share, prob_var=1/n_var, eta=eta)`` on the rows of X, on arrays.

    ``eta`` is one distribution index for every row or one per row (shape (n,)); pymoo's ``mut_pm`` takes
    one per row either way, so the draws do not depend on it.

    The arithmetic is pymoo's ``mut_pm`` (Deb's polynomial mutation, each variable with probability
    1/n_var), written on arrays in :func:`polynomial_steps`, and the draws are those of the operator's
    ``do`` in the same order (``mut_pm``'s, then one uniform per row for the share), so the result is the
    operator's bit for bit; what is left out is building a Population of Individuals around the rows and
    reading them back, which cost more than the mutation itself.

    Returns
    -------
    ndarray, shape (n, n_var)
        A new array: the mutated rows where a uniform draw ≤ ``share``, the others as in X.
    """
    n, n_var = X.shape
    X = np.asarray(X, dtype=float)
    if np.ndim(eta) == 0:
        etas = np.full(n, float(eta))
    else:
        etas = np.array(np.broadcast_to(np.asarray(eta, dtype=float), (n,)))
    mutated = polynomial_steps(X, xl, xu, etas, 1.0 / n_var, random_state)
    hit = random_state.random(size=n) <= share
    out = X.copy()
    out[hit] = mutated[hit]
    return out


def uniform_reset(X: np.ndarray, xl: np.ndarray, xu: np.ndarray, share: float,
                  random_state: np.random.Generator) -> np.ndarray:
    """One variable of round(share × n) rows of X, rows and variable drawn at random, redrawn uniformly in its bounds.

    A uniform redraw of one variable, like Coello 2004's mutation early in its run, reaches any
    point of that variable's range in one step, which the polynomial mutation's steps (even with
    η = 3) practically never do from far away: a distance variable caught in the second basin of
    MW2's g, 0.5–0.9 from its optimum, needs a step into a window of about 0.08 there (issue 33,
    docs/MOPSO.md).

    Draws: the rows (without replacement), then the variables, then the values.

    Returns
    -------
    ndarray, shape (n, n_var)
        A new array.
    """
    n, n_var = X.shape
    k = int(round(share * n))
    X = np.array(X, dtype=float)
    rows = random_state.choice(n, size=k, replace=False)
    columns = random_state.integers(n_var, size=k)
    X[rows, columns] = xl[columns] + random_state.random(k) * (xu[columns] - xl[columns])
    return X


def sbx_children(first: np.ndarray, second: np.ndarray, xl: np.ndarray, xu: np.ndarray,
                 random_state: np.random.Generator, probability: float = 0.9, eta: float = 15.0) -> np.ndarray:
    """One child per pair of pymoo's ``SBX(prob=probability, eta=eta, n_offsprings=1)``, on arrays.

    pymoo's ``cross_sbx`` (each variable with probability 0.5, the two children exchanged per variable
    with probability 0.5), written on arrays in :func:`sbx_pairs`, does the crossover, and the draws are
    those of ``Crossover.do`` and ``SBX._do`` in their order: which pairs cross, the exchange
    probability's draw, ``cross_sbx``'s, which of the two children is kept, and for a pair that does not
    cross, which parent is copied. The children are the operator's bit for bit.

    Parameters
    ----------
    first, second : ndarray, shape (n, n_var)
        The parents of each child.

    Returns
    -------
    ndarray, shape (n, n_var)
    """
    X = np.array((first, second), dtype=float)
    n = X.shape[1]
    children = np.empty_like(X[0])
    cross = random_state.random(n) < probability
    if cross.any():
        random_state.random((n, 1))  # SBX._do's draw against prob_exch = 1: never disables a pair
        Q = sbx_pairs(X, xl, xu, eta, random_state)
        second_child = random_state.random(size=n) < 0.5
        Q[0, second_child] = Q[1, second_child]
        children[cross] = Q[0, cross]
    copied = np.flatnonzero(~cross)
    if len(copied):
        # the operator draws ``choice(np.arange(2), size=1, replace=False)`` per pair: one bounded 32-bit draw
        # each, the draws ``integers(2, size=k)`` makes in one call (tests/test_mopso_arrays.py checks)
        children[copied] = X[random_state.integers(2, size=len(copied)), copied]
    return children


def sbx_pairs(X: np.ndarray, xl: np.ndarray, xu: np.ndarray, eta: float,
              random_state: np.random.Generator) -> np.ndarray:
    """Both children of each pair of pymoo's ``cross_sbx`` (variables and exchange with probability 0.5), on arrays.

    The same arithmetic as ``cross_sbx(X, xl, xu, eta * c, 0.5 * c, 0.5 * c)`` of pymoo 0.6 (``c`` a column
    of ones), expression for expression on the same elements, and its draws in its order: one uniform per
    variable and pair (crossed when below 0.5; never where the parents are within 1e-14 or ``xl == xu``), one
    per crossed variable for the spread, one per crossed variable for the exchange. Without pymoo's (n, n_var)
    copies of the bounds and parameters and its repeated mask indexing (issue 32); ``tests/test_mopso_serial.py``
    compares the two on random inputs.

    Parameters
    ----------
    X : ndarray, shape (2, n, n_var)
        The parents of each pair.

    Returns
    -------
    ndarray, shape (2, n, n_var)
        The two children of each pair, a new array.
    """
    _, n, n_var = X.shape
    cross = random_state.random((n, n_var)) < 0.5
    cross[np.abs(X[0] - X[1]) <= 1.0e-14] = False
    cross[:, xl == xu] = False
    rows, columns = np.nonzero(cross)
    p1, p2 = X[0, rows, columns], X[1, rows, columns]
    smaller = p1 < p2
    y1, y2 = np.where(smaller, p1, p2), np.where(smaller, p2, p1)
    low, high = xl[columns], xu[columns]
    # cross_sbx's two draws of one uniform per crossed variable (the spread, then the exchange) in one call: a
    # Generator's doubles come one 64-bit output each, so random(2k) is random(k) followed by random(k)
    draws = random_state.random(2 * len(p1))
    rand, exchange_draws = draws[:len(p1)], draws[len(p1):]
    # pymoo's η per crossed variable, and its exponents: the same floats for every use (computed once)
    etas = np.full(len(p1), float(eta))
    exponent, root = -(etas + 1.0), 1.0 / (etas + 1.0)

    def spread(beta):
        alpha = 2.0 - np.power(beta, exponent)
        threshold, scaled = 1.0 / alpha, rand * alpha
        inside = np.power(scaled, root)
        outside = np.power((1.0 / (2.0 - scaled)), root)
        # pymoo leaves 0 where neither comparison holds (1 / alpha NaN)
        return np.where(rand <= threshold, inside, np.where(rand > threshold, outside, 0.0))

    delta = y2 - y1
    c1 = 0.5 * ((y1 + y2) - spread(1.0 + (2.0 * (y1 - low) / delta)) * delta)
    c2 = 0.5 * ((y1 + y2) + spread(1.0 + (2.0 * (high - y2) / delta)) * delta)
    child1, child2 = np.where(smaller, c1, c2), np.where(smaller, c2, c1)
    exchange = np.bitwise_xor(exchange_draws < 0.5, p1 > p2)
    Q = np.array(X, dtype=float)
    Q[0, rows, columns] = np.where(exchange, child2, child1)
    Q[1, rows, columns] = np.where(exchange, child1, child2)
    return to_bounds(Q, xl, xu)


def round_integers(X: np.ndarray, is_integer: np.ndarray | None, xl: np.ndarray,
                   xu: np.ndarray) -> np.ndarray:
    """Integer coordinates rounded to the nearest integer inside [⌈xl⌉, ⌊xu⌋] (a new array).

    The rounding is the integer :class:`~mosd.validation.Interval`'s (ties to even, clipped
    into the box), the same the tuning problem and the detectors apply.

    Parameters
    ----------
    X : ndarray, shape (n, n_var)
    is_integer : ndarray of bool, shape (n_var,), or None
        None or all False: X is returned unchanged.
    xl, xu : ndarray, shape (n_var,)
    """
    if is_integer is None or not is_integer.any():
        return X
    X = np.array(X, dtype=float)
    box = Interval(xl[is_integer], xu[is_integer], integer=True)
    X[:, is_integer] = box.round(X[:, is_integer], clip=True)
    return X

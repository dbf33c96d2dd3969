"""Grid-archive multi-objective particle swarm optimiser (paper 000, §2.2.2).

The algorithm is the MOPSO of Coello Coello, Pulido & Lechuga, "Handling multiple
objectives with particle swarm optimization", IEEE Trans. Evol. Comput. 8(3),
256–279, 2004, as paper 000 uses it to minimise (FAR, MDR) over the chart parameters
(eq. 36): an external archive of non-dominated solutions on an adaptive hypercube
grid, truncated by eq. 37 when over capacity, leaders drawn from sparsely populated
cells, and a velocity/position update (eqs. 38–39).

One class, two presets:

* ``MOPSO()`` — the robust default, a swarm/recombination hybrid: each generation 30 % of
  the evaluations are particle moves and 70 % are children of archive members (crossover
  and mutation, ``recombination=0.7``), the share that made it robust (issues 21 and 33,
  ``docs/MOPSO.md``). It keeps the grid archive, eq. 37 and the
  density-based (roulette) leader choice, and changes what measurements on ZDT1–4,
  ZDT6, a ZDT1 with its optimum inside the box, and DTLZ2 (:mod:`mosd.optim.benchmarks`,
  ``docs/MOPSO.md``) showed to matter: inertia and social coefficients that decrease
  over the run, positions that stay on a bound they crossed (``boundary="clip"``),
  polynomial mutation of a share of the swarm, a personal best that follows the
  particle unless dominated, and, inside eq. 37, removal of the most crowded member
  of a cell rather than a random one — which in three or more objectives, where
  most cells hold one member, is what keeps the archive spread — with the archive's
  extremes kept; velocities are clamped to each variable's range. While the archive
  is less than half full, particles make SMPSO's constricted, partly repulsive move
  (``exploration``, :func:`smpso_velocity`): on multimodal landscapes (ZDT4, DTLZ1,
  DTLZ3) the attraction-only swarm collapsed onto a local front (issue 21). And 70 % of
  each generation's evaluations are archive offspring (``recombination``,
  :meth:`MOPSO._archive_offspring`: crossover and long-tailed mutation of two archive
  members), which combine what particles cannot (WFG4's separable multimodal distance
  variables, OSY's disconnected feasible regions) and re-spread an archive that has
  collapsed onto one point (ZDT2) (issue 21).
  While nothing feasible has been found, the archive holds a bounded set of the least
  infeasible points instead of the single least infeasible one (``infeasible="diverse"``,
  issue 33): leaders and parents stay diverse from an infeasible start (MW1). On a constrained
  problem, particles and offspring take NSGA-II's fine mutation steps (η = 20,
  ``constrained_fine_mutation``) from the first generation, and a share of the offspring gets one
  variable redrawn uniformly (``constrained_reset``: 30 % until the archive is feasible and full,
  10 % afterwards), which makes the long jumps instead (OSY's disconnected regions) and lets the
  archive leave a local front such as MW2's; once the archive is feasible and full, leaders and
  parents are drawn by crowding distance and truncation removes the most crowded members over the
  whole archive (``constrained``). From half the planned run on, a constrained run refines the front it
  found: 30 % of the offspring are an archive member (a third of them the ends of the front) with every
  variable moved by a small polynomial step, and the mutation takes η 50 (``constrained_late_phase``,
  ``constrained_refine``): the IGD gap to NSGA-II was convergence at the ends and kinks of the front, on
  constraint boundaries. That spread and converged the constrained fronts (MW2, MW3, MW7, CTP2, CTP3,
  issue 33). Unconstrained runs are unaffected.
* ``MOPSO(**PAPER_PRESET)`` (``MOPSO.paper()``, ``optimizer=mopso_paper``) — the paper's
  pure swarm, paper 000's Table 2 literally (every evaluation a particle move): constriction
  w = 0.7298, c1 = c2 = 1.4962, velocities reflected at the bounds, roulette-wheel leaders,
  Coello's mutation, random removal inside eq. 37, Coello's constraint handling; with the
  same seed it gives the same archive as this module did before the robust default.

The archive (grid, eq. 37, leader choice) and the constrained dominance live in
:mod:`mosd.optim.archive`; this module keeps the swarm. The swarm's state is arrays; pymoo's
individuals are built only where its API needs them: :meth:`MOPSO.next` runs a generation on arrays
and hands pymoo's ``advance`` an :class:`EvaluatedArrays`, whose individuals are built when the archive
keeps a candidate or something reads ``pop`` (``res.pop``, ``res.history``, callbacks); ``ask``/``tell``
and other evaluators get Populations (:func:`new_population`, evaluated by :class:`ArrayEvaluator`, which
hands X, F and CV back as arrays). Per-candidate ``Individual`` and ``Population`` bookkeeping, and
pymoo's operator functions' per-call overhead on a swarm of 100 (:func:`polynomial_steps`,
:func:`sbx_pairs` do their arithmetic and draws on arrays), were most of the optimiser's own time per
generation (issue 32): on the project's 2-core machine the main command's (swarm of 100) fell from 2.6–2.8 ms to
1.2–1.3 ms a generation, measured side by side with the code before at load average about 1.

Where the paper and Coello 2004 leave a detail open, the choice is documented at the
place that implements it:

* order of eqs. 38/39 — :meth:`MOPSO._infill`;
* how eq. 37 walks over the grid cells — :func:`~mosd.optim.archive.eq37_removal_counts`
  and :meth:`~mosd.optim.archive.GridArchive._truncate`;
* duplicates and constraints in the archive — :meth:`~mosd.optim.archive.GridArchive.update`;
* the run length that schedules and Coello's mutation refer to —
  :meth:`MOPSO._planned_generations`.

Paper 000's step 4 also says to stop ("jump to step 7") once the archive is full; this
implementation does not: the run length is pymoo's termination criterion (the paper's
Table 2 uses M = 100 iterations), because an archive of 100 fills within a few
generations and stopping there would make M meaningless.

Integer variables: a problem may carry ``is_integer``, a boolean array of length
``n_var`` (absent: all real). Those coordinates are rounded to the nearest integer in
[⌈xl⌉, ⌊xu⌋] after sampling, every move and every mutation, so each evaluated X and
``res.X`` is integral there. Velocities stay real: rounding repairs the position and
leaves the swarm dynamics (eq. 39) as they are.
"""
from __future__ import annotations

import math
import operator
import warnings

import numpy as np
from pymoo.core.algorithm import Algorithm
from pymoo.core.evaluator import Evaluator
from pymoo.core.individual import Individual, calc_cv
from pymoo.core.population import Population
from pymoo.core.sampling import Sampling
from pymoo.operators.sampling.rnd import FloatRandomSampling
from pymoo.termination.max_eval import MaximumFunctionCallTermination
from pymoo.termination.max_gen import MaximumGenerationTermination
from pymoo.util.display.multi import MultiObjectiveOutput

from .. import kernels
from ..validation import ConfigError, Interval, check_choice, check_in, check_int
from .archive import (CONSTRAINED_RULES, INFEASIBLE_RULES, LEADER_RULES, REMOVAL_RULES, GridArchive,
                      evaluated_arrays, pairwise_dominates)

#: φ = φ1 + φ2 of Clerc & Kennedy's constriction factor; paper 000 (below eq. 39) uses 4.1.
CONSTRICTION_PHI = 4.1
#: Coello 2004's inertia variant: W = 0.4 and unit acceleration coefficients.
COELLO_INERTIA = (0.4, 1.0, 1.0)
#: The default's coefficients: inertia 0.6 → 0.2 and social 1.75 → 1.0 over the run, cognitive 1.0
#: (chosen on ZDT1–3, a shifted ZDT1 and DTLZ2, docs/MOPSO.md).
SCHEDULED = ((0.6, 0.2), 1.0, (1.75, 1.0))
#: Velocity variants: which (w, c1, c2) an unset coefficient takes.
VELOCITIES = ("scheduled", "constriction", "inertia")
#: Iterations M of paper 000's Table 2: the run length assumed when nothing else tells it.
PAPER_MAX_ITERATIONS = 100
#: Ways to treat a particle that leaves the box, see :func:`apply_bounds`.
BOUNDARY_RULES = ("clip", "reflect", "absorb")
#: Personal-best update, see :meth:`MOPSO._update_personal_best`.
PERSONAL_BEST_RULES = ("dominance", "coin")
#: Mutation operators, see :meth:`MOPSO._infill`.
MUTATIONS = ("polynomial", "coello")
#: SMPSO's move (Nebro et al. 2009): c1, c2 ~ U[1.5, 2.5] per particle and move, inertia 0.1,
#: velocity clamp ±0.5 (xu − xl); see :func:`smpso_velocity`.
SMPSO_C_RANGE = (1.5, 2.5)
SMPSO_INERTIA = 0.1
SMPSO_MAX_VELOCITY = 0.5
#: an empty array: no velocity clamp, or no distribution indices, for the compiled move (never written to)
_NO_LIMIT = np.empty(0)
#: The archive offspring's simulated binary crossover (see :meth:`MOPSO._archive_offspring`): pymoo's
#: defaults, which are its NSGA-II's (probability 0.9 per pair, η = 15, each variable with probability 0.5).
CROSSOVER_PROBABILITY = 0.9
CROSSOVER_ETA = 15.0
#: The polynomial mutation's distribution index of NSGA-II (pymoo's default): the fine steps a share
#: ``constrained_fine_mutation`` of the particles and archive offspring takes on a constrained problem.
FINE_MUTATION_ETA = 20.0
#: ``constrained_reset``'s default: the share of a constrained problem's archive offspring with one variable redrawn
#: uniformly in its bounds: (until the archive is feasible and full, from then on). The redraw replaces the long
#: steps of η = 3 that the fine mutation gives up from the first generation: 0.3 kept OSY's disconnected regions and
#: MW2 off its local front, 0.1 afterwards the convergence of MW3 (issue 33, docs/MOPSO.md).
CONSTRAINED_RESET = (0.3, 0.1)
#: ``constrained_refine``'s default: the share of a constrained problem's archive offspring that are refinement
#: children (:meth:`MOPSO._refined_children`) in the late phase (``constrained_late_phase``). Screened at 0.2, 0.3 and
#: 0.4 (issue 33, fifth change, docs/MOPSO.md): 0.3 met four IGD targets on seeds 1–5 that 0.2 left CTP2 short of.
CONSTRAINED_REFINE = 0.3
#: The refinement children's polynomial mutation index: steps of about 1 % of each variable's range (the mean of
#: |δ| is 1 / (η + 2)), every variable at once — a local search around a member near the constraint boundary.
REFINE_ETA = 100.0
#: The share of the refinement children whose parent is an end of the front (the members with the smallest value of
#: each objective, in turn) rather than a leader-rule draw: on MW3 the ends of the front were where the archive lay
#: furthest from it (on bad seeds it stopped at f1 0.87–0.96 of a front reaching 1), and the crowding tournament gives
#: each end about 2 % of the draws (issue 33, fifth change, docs/MOPSO.md).
REFINE_ENDS = 1.0 / 3.0
#: ``constrained_late_phase``'s default: the share of the planned run after which a constrained run refines the front
#: it found: refinement children (``constrained_refine``) and the polynomial mutation index :data:`LATE_FINE_ETA` for
#: particles and archive offspring. From the first feasible point on, refinement cost OSY one of its disconnected
#: regions on seed 1 (docs/MOPSO.md).
CONSTRAINED_LATE_PHASE = 0.5
#: The mutation index of that late phase: steps of about 2 % of a variable's range, where η 20 makes 5 %.
LATE_FINE_ETA = 50.0
#: Exponent of Coello's mutation decay law (1 - t / (T p_m))^1.5 (see :meth:`MOPSO._coello_mutation`).
MUTATION_DECAY_EXPONENT = 1.5

#: Paper 000's Table 2 (with Coello 2004 where the paper is silent) as constructor arguments.
PAPER_PRESET = dict(archive_size=100, n_divisions=30, velocity="constriction", w=None, c1=None,
                    c2=None, max_velocity=None, boundary="reflect", leader="roulette",
                    personal_best="coin", removal="random", keep_extremes=False, mutation="coello",
                    mutation_rate=0.5, exploration=None, recombination=None, infeasible="least",
                    constrained="grid", constrained_fine_mutation=None, constrained_reset=None,
                    constrained_refine=None, constrained_late_phase=None)


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


def restart_pymoo_run(algorithm: Algorithm) -> None:
    """Make pymoo's next ``algorithm.next()`` run the initialisation again (a new run).

    pymoo 0.6 decides between ``_initialize_infill`` and ``_infill`` by the attribute
    ``is_initialized``, set in ``Algorithm.__init__`` and never reset by ``setup``; this is
    the one place that touches it (``tests/test_mopso.py::test_restart_adapter_matches_pymoo``
    fails loudly if a pymoo upgrade renames or stops reading it).
    """
    if not hasattr(algorithm, "is_initialized"):
        raise RuntimeError("pymoo's Algorithm no longer has is_initialized; "
                           "mosd.optim.mopso.restart_pymoo_run needs updating for this pymoo version")
    algorithm.is_initialized = False


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


#: what :class:`ArrayEvaluator` sets as attributes of the individuals (``Population.set`` does the rest)
_ARRAY_KEYS = ("F", "G", "H")


def new_population(X: np.ndarray, generation: int | None = None) -> Population:
    """``Population.new("X", X)``: one fresh :class:`~pymoo.core.individual.Individual` per row, built directly.

    The individuals are pymoo's own class in the state its constructor leaves them in, X set
    to the row of a copy of X owned by this population (``Population.set`` copies each row, so
    that no individual holds a view of a caller's array, pymoo #455); what is skipped is the generic
    path: a new configuration dictionary per individual (one shared, never modified, as pymoo
    only reads it) and ``Individual.set``'s attribute lookup per key and individual, which
    together cost more per generation than the swarm's whole move (issue 32). With ``generation``,
    each individual's data carry pymoo's ``n_gen`` and ``n_iter`` tags (what ``Algorithm.infill``
    sets afterwards, one individual at a time).
    """
    template, create = Individual().__dict__, Individual.__new__
    owned = np.array(X, dtype=float)
    rows = list(owned)
    built = []
    for row in rows:
        individual = create(Individual)
        state = individual.__dict__
        state.update(template)
        state["_X"], state["evaluated"] = row, set()
        state["data"] = {} if generation is None else {"n_gen": generation, "n_iter": generation}
        built.append(individual)
    population = _object_array(built).view(Population)
    # read by ArrayEvaluator.eval: nothing here is evaluated yet, and the rows of ``owned`` are the individuals' X
    # as long as each individual still holds its row (MOPSO.infill: and the tags are set)
    population._mosd_fresh, population._mosd_rows, population._mosd_tags = True, (owned, rows), generation
    return population


def _object_array(items: list) -> np.ndarray:
    """``items`` as a 1-d object array (``np.array`` would look into the individuals for a shape)."""
    array = np.empty(len(items), dtype=object)
    array[:] = items
    return array


def _constraint_violation(out: dict, n: int, config: dict) -> np.ndarray:
    """CV (n, 1) of a problem's output, as ``Individual.CV`` computes it for each row.

    pymoo's ``calc_cv`` on the whole G and H arrays loops over the rows with the function ``Individual.CV``
    calls; a problem with constraints but none set gives a scalar, broadcast to every row.
    """
    return np.array(np.broadcast_to(calc_cv(G=out.get("G"), H=out.get("H"), config=config), (n,)),
                    dtype=float).reshape(-1, 1)


def _population_X(pop: Population) -> np.ndarray:
    """The individuals' X as one new array: a copy of :func:`new_population`'s array while every individual still
    holds its row of it (nothing replaced an X since), else read from the individuals."""
    owned, rows = getattr(pop, "_mosd_rows", (None, None))
    if rows is not None and len(rows) == len(pop) and all(map(operator.is_, [ind._X for ind in pop], rows)):
        return owned.copy()
    return np.array([individual._X for individual in pop])


class ArrayEvaluator(Evaluator):
    """pymoo's :class:`~pymoo.core.evaluator.Evaluator` that sets the results on the individuals directly.

    The same problem call and the same attributes as the base class (F, G, H as rows of a copy of
    the problem's output, ``evaluated``, CV where the problem has constraints, computed by pymoo's
    ``calc_cv`` row by row as ``Individual.CV`` would), without ``Population.get``/``set``'s
    generic per-key, per-individual lookups; the evaluated arrays are kept in
    :attr:`last` (population, X, F, CV) so that :class:`MOPSO` does not read them back.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.last: tuple | None = None
        self._arrays: tuple | None = None

    def eval(self, problem, pop, skip_already_evaluated=None, evaluate_values_of=None, count_evals=True, **kwargs):
        self.last = self._arrays = None
        fresh = getattr(pop, "_mosd_fresh", False)
        if fresh and len(pop):
            # :func:`new_population`'s individuals have nothing evaluated: the base class's check of every
            # individual's ``evaluated`` set would select them all
            values = self.evaluate_values_of if evaluate_values_of is None else evaluate_values_of
            self._eval(problem, pop, values, **kwargs)
            if count_evals:
                self.n_eval += len(pop)
            if self.callback:
                self.callback(pop)
            pop._mosd_fresh = False
        else:
            pop = super().eval(problem, pop, skip_already_evaluated, evaluate_values_of, count_evals, **kwargs)
        # the arrays describe ``pop`` when every individual was evaluated now (the base class passes pop[I])
        if self._arrays is not None and isinstance(pop, Population) and len(self._arrays[0]) == len(pop):
            self.last = (pop, *self._arrays[1:])
        self._arrays = None
        return pop

    def _eval(self, problem, pop, evaluate_values_of, **kwargs):
        X = _population_X(pop)
        out = problem.evaluate(X, return_values_of=evaluate_values_of, return_as_dictionary=True, **kwargs)
        keys = set(out.keys())
        # one copy per key (the problem may reuse its output buffers); each individual gets a row of it, the
        # memory Population.set's copy of every row (pymoo #455) protects being this population's own
        owned = {key: np.array(value, copy=True) for key, value in out.items() if value is not None}
        names = ["_" + key for key in owned if key in _ARRAY_KEYS]
        columns = [list(owned[key]) for key in owned if key in _ARRAY_KEYS]
        others = {key: value for key, value in owned.items() if key not in _ARRAY_KEYS}
        CV = None
        if problem.has_constraints() and len(pop):
            CV = _constraint_violation(out, len(pop), pop[0].config)
            names.append("_CV")
            columns.append(list(CV))
        for individual, *rows in zip(pop, *columns):
            state = individual.__dict__
            state.update(zip(names, rows))
            state["evaluated"].update(keys)
        if others:
            pop.set(**others)
        self._arrays = (pop, X, owned["F"], CV if CV is not None else np.zeros((len(pop), 1)))


class EvaluatedArrays:
    """One generation's evaluated candidates as arrays, whose pymoo individuals are built when something asks.

    What :meth:`MOPSO.next` hands to ``advance`` instead of a Population: the swarm reads the arrays,
    :meth:`GridArchive.update` asks for the individuals of the candidates it keeps (:meth:`select`), and
    ``algorithm.pop``/``off`` (``res.pop``, ``res.history``, callbacks) for all of them (:meth:`population`).
    Each individual is built once, on first request, exactly as :func:`new_population` and
    :class:`ArrayEvaluator` build it (X a row of a copy taken before the evaluation, F/G/H rows of copies of the
    problem's output, CV where the problem has constraints, ``evaluated``, the ``n_gen``/``n_iter`` tags), so
    the archive's members and ``pop`` share the same objects as before. Building and freeing a hundred
    individuals a generation that nothing reads was the largest part of the optimiser's own time (issue 32).
    """

    def __init__(self, X: np.ndarray, out: dict, CV: np.ndarray | None, generation: int, config: dict,
                 evaluated_X: np.ndarray | None = None):
        self.X = X
        self.keys = set(out.keys())
        self.outputs = {key: np.array(value, copy=True) for key, value in out.items() if value is not None}
        self.CV = CV
        #: X (the array the problem evaluated), F, CV (n, 1; zeros without constraints): what the swarm reads
        self.swarm = (X if evaluated_X is None else evaluated_X, self.outputs.get("F"),
                      CV if CV is not None else np.zeros((len(X), 1)))
        self.generation = generation
        self.config = config
        self.individuals = np.full(len(X), None, dtype=object)
        self._population: Population | None = None

    def __len__(self) -> int:
        return len(self.X)

    def select(self, index: np.ndarray) -> Population:
        """The individuals of rows ``index`` (int array), built where not yet."""
        chosen = self.individuals[index]
        missing = index[np.equal(chosen, None)]
        if len(missing):
            self._build(missing.tolist())
            chosen = self.individuals[index]
        return chosen.view(Population)

    def population(self) -> Population:
        """All the individuals, in row order (the same Population object on every call)."""
        if self._population is None:
            self._population = self.select(np.arange(len(self.X)))
        return self._population

    def _build(self, rows: list[int]) -> None:
        template, create = Individual().__dict__, Individual.__new__
        template["config"] = self.config
        columns = [("_" + key, value) for key, value in self.outputs.items() if key in _ARRAY_KEYS]
        if self.CV is not None:
            columns.append(("_CV", self.CV))
        X, keys, tag = self.X, self.keys, self.generation
        built = []
        for i in rows:
            individual = create(Individual)
            state = individual.__dict__
            state.update(template)
            state["_X"], state["evaluated"], state["data"] = X[i], set(keys), {"n_gen": tag, "n_iter": tag}
            for name, values in columns:
                state[name] = values[i]
            built.append(individual)
        others = {key: value for key, value in self.outputs.items() if key not in _ARRAY_KEYS}
        for key, values in others.items():
            for i, individual in zip(rows, built):
                # Population.set's copy of a view (pymoo #455)
                value = values[i]
                individual.set(key, value.copy() if isinstance(value, np.ndarray) and not value.flags["OWNDATA"]
                               else value)
        self.individuals[rows] = _object_array(built)


class MOPSO(Algorithm):
    """Grid-archive multi-objective PSO of Coello et al. 2004 as used by paper 000.

    The defaults are the robust variant, a swarm/recombination hybrid (70 % of each
    generation's evaluations are archive offspring, ``recombination``); ``MOPSO(**PAPER_PRESET)``
    (or :meth:`MOPSO.paper`, ``optimizer=mopso_paper``) is paper 000's Table 2, the paper's
    pure swarm. Each move (eqs. 38–39, velocity first):

        v ← w v + c1 r1 (pbest − x) + c2 r2 (leader − x),  v clamped to ±max_velocity Δ,
        (while the archive is small, SMPSO's move instead for some particles: ``exploration``)
        x ← x + v,  then the bound rule, mutation and integer rounding,

    with r1, r2 ~ U(0, 1) per particle and dimension, a leader per particle and move
    drawn from the archive, and Δ = xu − xl per variable. With ``recombination`` r, only
    the first N − round(r N) slots move so; the last round(r N) are filled each generation
    by children of archive members (:meth:`_archive_offspring`).

    Parameters
    ----------
    pop_size : int
        Number of particles N (Table 2: 100).
    archive_size : int
        Archive capacity Z_ar (Table 2: 100).
    n_divisions : int
        Grid intervals per objective (Coello 2004: 30; default 50, measured slightly
        better on ZDT2/ZDT3 and no worse elsewhere).
    velocity : {"scheduled", "constriction", "inertia"}
        Where unset coefficients (``w``, ``c1``, ``c2`` = None) come from.
        "scheduled" (the default): w 0.6 → 0.2, c1 = 1, c2 1.75 → 1.0 linearly over the
        run — a decreasing inertia as in Shi & Eberhart 1998; the social coefficient
        falls as well (unlike Ratnaweera et al.'s 2004 TVAC): early moves overshoot the
        leader (c2 r2 > 1), late ones contract onto it. Constant coefficients either
        converged on ZDT1 and stalled inside the box, or the reverse (docs/MOPSO.md).
        "constriction": paper 000 eq. 39 with Clerc's
        constriction factor, φ = 4.1 → w = 0.7298, c1 = c2 = 1.4962 (Table 2).
        "inertia": Coello 2004's W = 0.4, c1 = c2 = 1.
    w, c1, c2 : float, pair of float, or None
        Inertia weight and cognitive / social coefficients, >= 0. A pair [start, end]
        changes linearly from the first move to the last planned one (see ``horizon``)
        and stays at ``end`` afterwards.
    max_velocity : float or None
        Each velocity component is clamped to ±max_velocity × (xu − xl) before the move
        (SMPSO: 0.5). None: no clamp (paper 000 and Coello 2004). The default 1.0 (at
        most the variable's range per move) measured as good as no clamp and better than
        0.5 with the scheduled coefficients, and still stops a diverging swarm.
    boundary : {"clip", "reflect", "absorb"}
        What an out-of-range coordinate does to its velocity (:func:`apply_bounds`);
        "reflect" is paper 000's and Coello's rule.
    leader : {"roulette", "tournament"}
        Leader choice from the grid (:meth:`GridArchive.select_leaders`).
    personal_best : {"dominance", "coin"}
        pbest update (:meth:`_update_personal_best`); "coin" is Coello 2004's.
    removal : {"crowding", "random"}
        Which members of a crowded cell eq. 37 removes (:meth:`GridArchive._truncate`).
    keep_extremes : bool
        Truncation never removes the archive's best member in any objective.
    mutation : {"polynomial", "coello"} or None
        "polynomial": each move, a share ``mutation_rate`` of the particles (drawn at
        random) gets Deb's polynomial mutation with probability 1/n_var per variable and
        distribution index ``mutation_eta`` (pymoo's ``PolynomialMutation``; SMPSO: one
        particle in six, η = 20). "coello": Coello 2004's operator
        (:meth:`_coello_mutation`), active during the first ``mutation_rate`` of the run.
        None: no mutation (paper 000 does not mention one).
    mutation_rate : float or None
        In (0, 1]: the share of particles mutated per move ("polynomial"), or Coello's p_m,
        the share of the run during which mutation acts ("coello"). None: no mutation
        (the pre-existing key's meaning).
    mutation_eta : float
        Distribution index of the polynomial mutation (of particles and of archive
        offspring), >= 0. Default 3: long-tailed steps, chosen (issue 21) so that offspring
        jump between OSY's disconnected feasible regions (20, the issue-14 value: mostly steps
        of about 5 % of the range; docs/MOPSO.md). On a problem with constraints, OSY
        included, ``constrained_fine_mutation`` now replaces it by 20 and the redraw of
        ``constrained_reset`` makes those jumps (issue 33).
    exploration : float in (0, 1] or None
        While the archive holds fewer than ``exploration`` × ``archive_size`` members,
        the first ⌈s N⌉ particles, s = 1 − |A| / (``exploration`` × Z_ar)
        (:meth:`_exploring_share`), make SMPSO's constricted move (:func:`smpso_velocity`)
        instead of the velocity variant's. Default 0.5: what lets the swarm leave the local
        fronts of ZDT4, DTLZ1 and DTLZ3 (issue 21, docs/MOPSO.md). None: never (the
        issue-14 default and the paper preset).
    recombination : float in (0, 1) or None
        Share r of the swarm's N slots filled each move by archive offspring instead of
        particle moves: round(r N) children (at most N − 1) of two archive members each,
        drawn by the ``leader`` rule, through pymoo's SBX (η 15, probability 0.9) and
        polynomial mutation (``mutation_eta``, 1/n_var per variable)
        (:meth:`_archive_offspring`). Default 0.7 (issue 21, docs/MOPSO.md: 0.3–0.5 left
        WFG4 below 0.95 × NSGA-II). None: every slot is a particle (issue-14 default, paper
        preset).
    infeasible : {"diverse", "least"}
        What the archive holds while no feasible point has been found
        (:class:`~mosd.optim.archive.GridArchive`). "diverse" (default): the ⌈``archive_size`` / 2⌉
        least infeasible distinct points (constraint violation first, then crowding, as
        NSGA-II's constrained domination ranks its population), leaders and parents drawn from
        them by binary tournament on the violation; from the first feasible point on, the
        archive is the feasible non-dominated set as before. "least" (Coello 2004, the paper
        preset): the constrained dominance alone, which keeps only the least infeasible point,
        so that one point is every leader and both parents of every offspring until a feasible
        point is found (MW1: 60–100 generations, issue 33, docs/MOPSO.md).
    constrained : {"crowding", "grid"}
        How the feasible archive of a problem with constraints is kept spread. "crowding"
        (default): once the feasible archive is full (:data:`~mosd.optim.archive.SPREAD_FILL`),
        leaders and parents by NSGA-II's crowding-distance binary tournament, and truncation of
        the most crowded members over the whole archive rather than cell by cell
        (:class:`~mosd.optim.archive.GridArchive`); "grid" (paper preset): cells, eq. 37 and the
        ``leader`` rule, as on an unconstrained problem. With the grid rules the IGD of MW2, MW3,
        MW7, CTP2 and CTP3 was 1.3–1.7 × NSGA-II's (issue 33, docs/MOPSO.md). An unconstrained
        problem always uses the grid rules.
    constrained_fine_mutation : float in [0, 1] or None
        On a problem with constraints, this share of the archive offspring and of the mutated
        particles (the first round(share × n) rows) is mutated with NSGA-II's η = 20
        (:data:`FINE_MUTATION_ETA`) instead of ``mutation_eta``, from the first generation on: the
        optimum lies on a constraint boundary, where the long-tailed steps mostly leave the feasible
        region (issue 33, docs/MOPSO.md). Default 1 (all of them; the long jumps come from the uniform
        redraw of ``constrained_reset``); None or 0: none.
    constrained_reset : float in [0, 1], pair of them, or None
        On a problem with constraints, this share of each generation's archive offspring gets one
        variable, chosen at random, redrawn uniformly in its bounds after crossover and mutation
        (:func:`uniform_reset`); a pair [s1, s2]: s1 until the archive is feasible and full, s2 from
        then on. MW2's distance function has a second basin far from the optimum in each variable; on 2
        of 5 seeds the default settled there (a local front 0.04–0.1 above the true one), and the
        polynomial mutation's steps do not leave it; and with the fine mutation from the first generation
        the redraw is what still finds OSY's disconnected feasible regions while the archive fills
        (issue 33, docs/MOPSO.md). Default [0.3, 0.1] (21, then 7 of 70 offspring); None or 0: none.
    constrained_refine : float in [0, 1] or None
        On a problem with constraints, in the late phase (``constrained_late_phase``) and once the archive
        holds a feasible point, this share of each generation's archive offspring are refinement children
        instead of crossover children: an archive member (a third of them the ends of the front) with every
        variable moved by a polynomial step of η = :data:`REFINE_ETA` (:meth:`_refined_children`). The IGD
        gap to NSGA-II on MW3, MW7, CTP2 and CTP3 was convergence — archive points 0.01–0.04 off the front
        at its ends and kinks, which lie on constraint boundaries, and CTP3's isolated front points reached
        less closely — which crossover of distant members rarely refines (issue 33, fifth change,
        docs/MOPSO.md). Default 0.3 (21 of 70 offspring); None or 0: none.
    constrained_late_phase : float in [0, 1] or None
        On a problem with constraints, the share of the planned generations after which the run refines the
        front the first part found: the refinement children of ``constrained_refine``, and the mutated
        particles and all archive offspring with the polynomial mutation index :data:`LATE_FINE_ETA`
        instead of η 20 (the uniform redraw of ``constrained_reset`` goes on: stopping it left MW2 on its
        local front on 2 seeds of 10) (issue 33, fifth change, docs/MOPSO.md). Default 0.5; None: no late
        phase (and no refinement). Needs the run length (:meth:`_planned_generations`).
    horizon : int or None
        Run length in generations (the initial swarm included) that scheduled
        coefficients and Coello's mutation refer to. None: taken from the termination if
        it is a plain ``("n_gen", G)`` (G) or ``("n_eval", E)`` (⌈E / pop_size⌉)
        criterion; any other termination (time, tolerance, pymoo's default) does not say
        how long the run lasts, so paper 000's M = 100 is assumed, with a warning.
    sampling : pymoo Sampling, optional
        Initial positions; uniform in the bounds by default (paper 000 step 1).
    **kwargs
        Passed to :class:`pymoo.core.algorithm.Algorithm` (termination, callback,
        save_history, seed, …).

    Notes
    -----
    Median hypervolumes at 10,000 evaluations are in ``docs/MOPSO.md`` (and
    ``python -m mosd.optim.benchmarks``). ``res.X``/``res.F`` are the final archive. The
    archive lives in ``self.leader_archive`` because pymoo's base class reserves
    ``self.archive``. Every random draw uses ``self.random_state``, the Generator pymoo
    seeds in ``setup`` from ``seed``; ``setup`` also resets the swarm, so a second
    ``setup`` starts a new run.
    """

    def __init__(self, pop_size: int = 100, archive_size: int = 100, n_divisions: int = 50,
                 velocity: str = "scheduled", w=None, c1=None, c2=None,
                 max_velocity: float | None = 1.0, boundary: str = "clip",
                 leader: str = "roulette", personal_best: str = "dominance",
                 removal: str = "crowding", keep_extremes: bool = True,
                 mutation: str | None = "polynomial", mutation_rate: float | None = 0.15,
                 mutation_eta: float = 3.0, exploration: float | None = 0.5,
                 recombination: float | None = 0.7, infeasible: str = "diverse", constrained: str = "crowding",
                 constrained_fine_mutation: float | None = 1.0,
                 constrained_reset=CONSTRAINED_RESET, constrained_refine: float | None = CONSTRAINED_REFINE,
                 constrained_late_phase: float | None = CONSTRAINED_LATE_PHASE, horizon: int | None = None,
                 sampling: Sampling | None = None, output=None, **kwargs):
        # ArrayEvaluator unless the caller brings an evaluator (then the arrays are read back from the individuals)
        kwargs.setdefault("evaluator", ArrayEvaluator())
        super().__init__(output=MultiObjectiveOutput() if output is None else output, **kwargs)
        self.pop_size = check_int("optimizer.pop_size", pop_size, 1)
        self.archive_size = check_int("optimizer.archive_size", archive_size, 1)
        self.n_divisions = check_int("optimizer.n_divisions", n_divisions, 1)
        self.velocity = check_choice("optimizer.velocity", velocity, VELOCITIES)
        defaults = {"scheduled": SCHEDULED, "constriction": constriction_coefficients(),
                    "inertia": COELLO_INERTIA}[velocity]
        self.w, self.c1, self.c2 = (_coefficient(f"optimizer.{name}", value, default)
                                    for name, value, default in zip(("w", "c1", "c2"), (w, c1, c2), defaults))
        self.max_velocity = (None if max_velocity is None else
                             check_in("optimizer.max_velocity", max_velocity,
                                      Interval(0.0, math.inf, open_low=True, open_high=True)))
        self.boundary = check_choice("optimizer.boundary", boundary, BOUNDARY_RULES)
        self.leader = check_choice("optimizer.leader", leader, LEADER_RULES)
        self.personal_best = check_choice("optimizer.personal_best", personal_best, PERSONAL_BEST_RULES)
        self.removal = check_choice("optimizer.removal", removal, REMOVAL_RULES)
        self.keep_extremes = check_choice("optimizer.keep_extremes", keep_extremes, (True, False))
        self.mutation = check_choice("optimizer.mutation", mutation, (*MUTATIONS, None))
        self.mutation_rate = (None if mutation_rate is None else
                              check_in("optimizer.mutation_rate", mutation_rate,
                                       Interval(0.0, 1.0, open_low=True)))
        self.mutation_eta = check_in("optimizer.mutation_eta", mutation_eta,
                                     Interval(0.0, math.inf, open_high=True))
        self.exploration = (None if exploration is None else
                            check_in("optimizer.exploration", exploration, Interval(0.0, 1.0, open_low=True)))
        self.recombination = (None if recombination is None else
                              check_in("optimizer.recombination", recombination,
                                       Interval(0.0, 1.0, open_low=True, open_high=True)))
        self.infeasible = check_choice("optimizer.infeasible", infeasible, INFEASIBLE_RULES)
        self.constrained = check_choice("optimizer.constrained", constrained, CONSTRAINED_RULES)
        self.constrained_fine_mutation = (None if constrained_fine_mutation is None else
                                          check_in("optimizer.constrained_fine_mutation", constrained_fine_mutation,
                                                   Interval(0.0, 1.0)))
        self.constrained_reset = _reset_shares(constrained_reset)
        self.constrained_refine = (None if constrained_refine is None else
                                   check_in("optimizer.constrained_refine", constrained_refine, Interval(0.0, 1.0)))
        self.constrained_late_phase = (None if constrained_late_phase is None else
                                       check_in("optimizer.constrained_late_phase", constrained_late_phase,
                                                Interval(0.0, 1.0)))
        self.horizon = None if horizon is None else check_int("optimizer.horizon", horizon, 1)
        if sampling is not None and not isinstance(sampling, Sampling):
            raise ConfigError(f"optimizer.sampling={sampling!r} is not allowed; allowed: a pymoo Sampling")
        self.sampling = FloatRandomSampling() if sampling is None else sampling

        # swarm state, (re)built by _setup
        self.leader_archive: GridArchive | None = None
        self.particle_position: np.ndarray | None = None
        self.particle_velocity: np.ndarray | None = None
        self.pbest_X: np.ndarray | None = None
        self.pbest_F: np.ndarray | None = None
        self.pbest_CV: np.ndarray | None = None
        self.is_integer: np.ndarray | None = None
        self.constrained_problem = False
        self.planned_generations: int | None = None

    @classmethod
    def paper(cls, **overrides) -> "MOPSO":
        """Paper 000's Table 2 settings (:data:`PAPER_PRESET`), optionally overridden."""
        return cls(**{**PAPER_PRESET, **overrides})

    # -- pymoo lifecycle ------------------------------------------------------------------

    def _setup(self, problem, **kwargs):
        if not problem.has_bounds() or not (np.all(np.isfinite(problem.xl))
                                            and np.all(np.isfinite(problem.xu))):
            raise ConfigError("optimizer: the problem needs finite bounds xl, xu; allowed: finite bounds")
        self.is_integer = _integer_mask(problem)
        # issue 33: the crowding rules, the fine mutation and the redraw act on constrained problems only, so that an
        # unconstrained run (the presets' tuning problems, issue 21's table) is the same bit for bit
        self.constrained_problem = bool(problem.has_constraints())
        self.leader_archive = GridArchive(self.archive_size, self.n_divisions, self.removal,
                                          self.keep_extremes, self.infeasible,
                                          self.constrained if self.constrained_problem else "grid")
        self.particle_position = self.particle_velocity = None
        self.pbest_X = self.pbest_F = self.pbest_CV = None
        self.planned_generations = self._planned_generations()
        restart_pymoo_run(self)

    # pymoo keeps the current and the last evaluated population in ``pop`` and ``off``; :meth:`next` stores the
    # generation's arrays there (EvaluatedArrays) and the individuals are built when one of them is read
    @property
    def pop(self) -> Population | None:
        pop = self.__dict__.get("_pop")
        return pop.population() if isinstance(pop, EvaluatedArrays) else pop

    @pop.setter
    def pop(self, value) -> None:
        self.__dict__["_pop"] = value

    @property
    def off(self) -> Population | None:
        off = self.__dict__.get("_off")
        return off.population() if isinstance(off, EvaluatedArrays) else off

    @off.setter
    def off(self, value) -> None:
        self.__dict__["_off"] = value

    def next(self) -> None:
        """pymoo's ``Algorithm.next`` (infill, evaluate, advance) on arrays, when MOPSO's own evaluator evaluates.

        The positions of the move (or the initial sampling), one ``problem.evaluate`` of them as
        :class:`ArrayEvaluator` makes it (counted in ``evaluator.n_eval``), then pymoo's ``advance`` with an
        :class:`EvaluatedArrays`: the same draws and arithmetic as the Population path, without building the
        individuals nothing reads (issue 32). Another evaluator, an evaluator callback or pymoo's ``archive``
        take pymoo's own ``next``, and so does a subclass that overrides a hook of the Population path
        (``infill``, ``_infill``, ``_initialize_infill``); ``ask``/``tell`` keep returning and taking Populations.
        """
        evaluator, cls = self.evaluator, type(self)
        if (type(evaluator) is not ArrayEvaluator or evaluator.callback is not None or self.archive is not None
                or cls.infill is not MOPSO.infill or cls._infill is not MOPSO._infill
                or cls._initialize_infill is not MOPSO._initialize_infill):
            return super().next()
        if self.problem is None:
            raise Exception("Please call `setup(problem)` before calling next().")
        if not self.is_initialized:
            self._initialize()
            X = self._initial_positions()
        else:
            X = self._moved_positions()
        self.advance(infills=self._evaluate_positions(X))

    def _evaluate_positions(self, X: np.ndarray) -> EvaluatedArrays:
        """``X`` evaluated as :meth:`ArrayEvaluator.eval` evaluates :func:`new_population`'s individuals."""
        evaluator, problem = self.evaluator, self.problem
        config = Individual.default_config()
        owned = np.array(X, dtype=float)  # the individuals' rows: not the array the problem gets
        X = owned.copy()
        out = problem.evaluate(X, return_values_of=evaluator.evaluate_values_of, return_as_dictionary=True,
                               algorithm=self)
        CV = None
        if problem.has_constraints() and len(X):
            CV = _constraint_violation(out, len(X), config)
        evaluator.n_eval += len(X)
        return EvaluatedArrays(owned, out, CV, self.n_iter, config, evaluated_X=X)

    def _initial_positions(self) -> np.ndarray:
        sampling = self.sampling
        if type(sampling).do is Sampling.do:
            # Sampling.do is _do's array wrapped in Population.new("X", ·), which .get("X") reads back row by row
            X = sampling._do(self.problem, self.pop_size, algorithm=self, random_state=self.random_state)
            if isinstance(X, np.ndarray) and X.dtype == float and X.ndim == 2:
                X = X.copy()
            else:
                X = Population.new("X", X).get("X")
        else:
            X = sampling.do(self.problem, self.pop_size, algorithm=self, random_state=self.random_state).get("X")
        return round_integers(X, self.is_integer, self.problem.xl, self.problem.xu)

    def _initialize_infill(self):
        return new_population(self._initial_positions(), self.n_iter)

    def infill(self) -> Population | None:
        """pymoo's ``Algorithm.infill`` (initialise on the first call, then ``_infill``), tagging the infills'
        ``n_gen`` and ``n_iter`` (data of the individuals) without ``Population.set``'s per-individual lookups."""
        if self.problem is None:
            raise Exception("Please call `setup(problem)` before calling next().")
        if not self.is_initialized:
            self._initialize()
            infills = self._initialize_infill()
        else:
            infills = self._infill()
        if infills is not None and getattr(infills, "_mosd_tags", None) != self.n_iter:
            # not tagged by new_population (an override of _infill may return any population)
            for individual in infills:
                individual.data["n_gen"] = individual.data["n_iter"] = self.n_iter
        return infills

    def _evaluated(self, infills) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X, F, CV of the evaluated infills: :class:`EvaluatedArrays`' or :class:`ArrayEvaluator`'s arrays, else
        read from the individuals."""
        if isinstance(infills, EvaluatedArrays):
            return infills.swarm
        last = getattr(self.evaluator, "last", None)
        if last is not None and last[0] is infills:
            # read once: res.history's copies of the algorithm need not carry them
            self.evaluator.last = None
            return last[1:]
        return evaluated_arrays(infills, self.problem.has_constraints())

    def _initialize_advance(self, infills=None, **kwargs):
        # paper 000 step 1: v_0 = 0 and Pbest_0 = Pop_0
        X, F, CV = evaluated = self._evaluated(infills)
        self.particle_position = X
        self.particle_velocity = np.zeros_like(X, dtype=float)
        self.pbest_X, self.pbest_F, self.pbest_CV = X.copy(), F.copy(), CV.reshape(-1).copy()
        self.leader_archive.update(infills, self.random_state, evaluated)

    def _infill(self):
        """One move of the swarm (:meth:`_moved_positions`) as a Population."""
        return new_population(self._moved_positions(), self.n_iter)

    def _moved_positions(self) -> np.ndarray:
        """One move of the swarm, eqs. 38–39: the new positions, the archive offspring in the last slots.

        Paper 000 prints eq. 38 (x_{p+1} = x_p + v_p) before eq. 39 (the new velocity);
        taken literally with v_0 = 0 the first generation would re-evaluate the initial
        swarm. As Coello 2004 and Clerc & Kennedy do, the velocity is updated first and
        the position moves by the new velocity. r1, r2 are drawn per particle and
        dimension; each particle has its own leader. Move t (0-based) is generation
        n_iter = t + 2 of pymoo's count (generation 1 is the initial swarm).
        """
        rng, archive, problem = self.random_state, self.leader_archive, self.problem
        move = self.n_iter - 2
        n_offspring = self._n_offspring()
        # the last n_offspring slots are filled by archive offspring, the others move as particles
        n_particles = self.pop_size - n_offspring
        X, personal = self.particle_position[:n_particles], self.pbest_X[:n_particles]
        previous_velocity = self.particle_velocity[:n_particles]
        leaders = archive.X[archive.select_leaders(n_particles, rng, self.leader)]
        w, c1, c2 = (self._scheduled(value, move) for value in (self.w, self.c1, self.c2))
        compiled = self._compiled_move()
        if compiled is not None:
            X_new, velocity = self._compiled_particles(compiled, X, previous_velocity, personal, leaders, w, c1, c2)
        else:
            X_new, velocity = self._particles(X, previous_velocity, personal, leaders, w, c1, c2, move)
        if n_offspring:
            X_new = np.concatenate([X_new, self._archive_offspring(n_offspring)])
            velocity = np.concatenate([velocity, np.zeros((n_offspring, problem.n_var))])
        self.particle_velocity = velocity
        return round_integers(X_new, self.is_integer, problem.xl, problem.xu)

    def _compiled_move(self):
        """The compiled move (:mod:`mosd.kernels.swarm`) when it applies, else None (the NumPy code below).

        It applies when the kernels are on, the random state is a NumPy Generator, the boundary rule is one of
        :func:`apply_bounds`' and the particles' mutation is polynomial or none (Coello's stays NumPy code); on an
        empty cache, from the generation its compilation ahead ends (:func:`mosd.kernels.swarm.ready`).
        """
        if (not kernels.enabled() or type(self.random_state) is not np.random.Generator
                or self.boundary not in BOUNDARY_RULES
                or (self.mutation_rate is not None and self.mutation == "coello")):
            return None
        from ..kernels import swarm

        return swarm if swarm.ready() else None

    def _bit_source(self, swarm) -> np.ndarray:
        """:func:`mosd.kernels.swarm.bit_source` of the current random state, kept while it is the same generator
        with the same state (a copy of the algorithm, as in ``res.history``, carries a copy of the generator whose
        state lies elsewhere: it finds the kept addresses stale and takes its own)."""
        generator, cached = self.random_state, self.__dict__.get("_source")
        if (cached is None or cached[0] is not generator
                or cached[1][2] != generator.bit_generator.ctypes.state_address):
            cached = self.__dict__["_source"] = (generator, swarm.bit_source(generator))
        return cached[1]

    def _compiled_particles(self, swarm, X, previous_velocity, personal, leaders, w, c1, c2):
        """The particles' move of :meth:`_particles` in one call of :func:`mosd.kernels.swarm.particle_move`."""
        problem, n_particles = self.problem, len(X)
        xl, xu = np.asarray(problem.xl, dtype=float), np.asarray(problem.xu, dtype=float)
        limit = _NO_LIMIT if self.max_velocity is None else self.max_velocity * (xu - xl)
        share = self._exploring_share()
        n_exploring = min(n_particles, math.ceil(share * self.pop_size)) if share > 0.0 else 0
        mutate = self.mutation_rate is not None and self.mutation == "polynomial"
        return swarm.particle_move(
            np.ascontiguousarray(X, dtype=float), np.ascontiguousarray(previous_velocity, dtype=float),
            np.ascontiguousarray(personal, dtype=float), np.ascontiguousarray(leaders, dtype=float),
            float(w), float(c1), float(c2), limit, n_exploring, *SMPSO_C_RANGE, SMPSO_INERTIA,
            SMPSO_MAX_VELOCITY, xl, xu, swarm.BOUNDARY_CODES[self.boundary], mutate,
            self._eta_rows(n_particles) if mutate else _NO_LIMIT, float(self.mutation_rate) if mutate else 0.0,
            self._bit_source(swarm))

    def _eta_rows(self, n: int) -> np.ndarray:
        """:meth:`_mutation_etas` as one index per row (what the compiled mutation takes)."""
        etas = self._mutation_etas(n)
        return np.full(n, float(etas)) if np.ndim(etas) == 0 else np.asarray(etas, dtype=float)

    def _particles(self, X, previous_velocity, personal, leaders, w, c1, c2, move):
        """The particles' move on NumPy arrays: eq. 39's velocity, SMPSO's for the exploring ones, eq. 38 and
        the boundary rule, then the particles' mutation; the new positions and velocities."""
        rng, problem, n_particles = self.random_state, self.problem, len(X)
        r1, r2 = rng.random(X.shape), rng.random(X.shape)
        velocity = w * previous_velocity + c1 * r1 * (personal - X) + c2 * r2 * (leaders - X)
        if self.max_velocity is not None:
            limit = self.max_velocity * (problem.xu - problem.xl)
            velocity = np.clip(velocity, -limit, limit)
        share = self._exploring_share()
        if share > 0.0:
            # SMPSO's move for the first share × N particles, the same ones every move: the
            # others keep contracting onto the leaders, fill the archive and so end the
            # exploration (particles drawn afresh each move all kept being thrown off and
            # DTLZ3 stalled on 2 seeds of 5, docs/MOPSO.md). No draw when share is 0, which
            # keeps the paper preset's random stream as it was.
            exploring = np.arange(n_particles) < share * self.pop_size
            velocity[exploring] = smpso_velocity(X[exploring], previous_velocity[exploring],
                                                 personal[exploring], leaders[exploring], problem.xl,
                                                 problem.xu, rng)
        X_new, velocity = apply_bounds(X + velocity, velocity, problem.xl, problem.xu, self.boundary)
        if self.mutation_rate is not None and self.mutation == "coello":
            X_new = self._coello_mutation(X_new, move)
        elif self.mutation_rate is not None and self.mutation == "polynomial":
            # pymoo's operator: a share mutation_rate of the particles, each variable with 1/n_var
            X_new = polynomial_mutation(X_new, problem.xl, problem.xu, self._mutation_etas(n_particles),
                                        self.mutation_rate, rng)
        return X_new, velocity

    def _advance(self, infills=None, **kwargs):
        self.pop = infills
        evaluated = self._evaluated(infills)
        self.leader_archive.update(infills, self.random_state, evaluated)
        self._update_personal_best(*evaluated)

    def _set_optimum(self):
        self.opt = self.leader_archive.members.copy()

    # -- components -------------------------------------------------------------------------

    def _update_personal_best(self, X: np.ndarray, F: np.ndarray, CV: np.ndarray) -> None:
        """Move the particles to their evaluated positions and update pbest.

        ``"dominance"`` (SMPSO): pbest ← the new position unless pbest dominates it.
        ``"coin"`` (Coello 2004): pbest ← the new position if it dominates pbest, pbest
        stays if it dominates the new one, otherwise a fair coin decides. Dominance is
        feasibility-first (:func:`~mosd.optim.archive.dominance_matrix`).
        """
        CV = CV.reshape(-1)
        self.particle_position = X
        old_wins = pairwise_dominates(self.pbest_F, self.pbest_CV, F, CV)
        if self.personal_best == "coin":
            new_wins = pairwise_dominates(F, CV, self.pbest_F, self.pbest_CV)
            coin = self.random_state.random(len(X)) < 0.5
            replace = new_wins | (~old_wins & coin)
        else:
            replace = ~old_wins
        self.pbest_X[replace], self.pbest_F[replace], self.pbest_CV[replace] = X[replace], F[replace], CV[replace]

    def _n_offspring(self) -> int:
        """Slots of the swarm filled by archive offspring each move: round(``recombination`` × N), at most N − 1."""
        if not self.recombination:
            return 0
        return min(self.pop_size - 1, int(round(self.recombination * self.pop_size)))

    def _archive_offspring(self, n: int) -> np.ndarray:
        """``n`` children of archive members: simulated binary crossover, then polynomial mutation.

        Each child has two parents drawn by the leader rule (:meth:`GridArchive.select_leaders`,
        so members of sparse cells are preferred, as for leaders), pymoo's SBX (probability
        :data:`CROSSOVER_PROBABILITY`, η = :data:`CROSSOVER_ETA`, one child per pair) and
        pymoo's polynomial mutation of every child (1/n_var per variable, η = ``mutation_eta``).

        Why (issue 21, docs/MOPSO.md): a particle moves all its variables along one line
        towards its attractors, so it cannot combine the good distance variables of two
        members (WFG4's separable 30-minimum shift), and a swarm whose archive has
        collapsed onto one point has every attractor on that point (ZDT2's f1 = 0 end):
        only a mutated copy of a converged member enters such an archive. Crossover of
        archive members does both, as NSGA-II's variation does; its children of a
        one-member archive are mutated copies of it. On a problem with constraints, the mutation takes
        η = 20 (``constrained_fine_mutation``, :meth:`_mutation_etas`) and a share ``constrained_reset``
        of the children then gets one variable redrawn uniformly (:func:`uniform_reset`, :meth:`_reset_share`);
        in a constrained run's late phase the last round(``constrained_refine`` × n) children are refinement
        children instead (:meth:`_refined_children`), which the redraw may hit as well.
        """
        refined = self._refined_count(n)
        children = self._varied_children(n - refined)
        if refined:
            children = np.vstack([children, self._refined_children(refined)])
        share = self._reset_share()
        if share:
            problem = self.problem
            children = uniform_reset(children, problem.xl, problem.xu, share, self.random_state)
        return children

    def _varied_children(self, n: int) -> np.ndarray:
        """Crossover and polynomial mutation of the archive offspring (:meth:`_archive_offspring`)."""
        archive, problem, rng = self.leader_archive, self.problem, self.random_state
        if n == 0:
            return np.empty((0, problem.n_var))
        pairs = archive.select_leaders(2 * n, rng, self.leader).reshape(n, 2)
        compiled = self._compiled_move()
        if compiled is not None:
            first, second = archive.X[pairs[:, 0]].astype(float), archive.X[pairs[:, 1]].astype(float)
            return compiled.offspring(first, second, np.asarray(problem.xl, dtype=float),
                                      np.asarray(problem.xu, dtype=float), CROSSOVER_PROBABILITY, CROSSOVER_ETA,
                                      self._eta_rows(n), self._bit_source(compiled))
        children = sbx_children(archive.X[pairs[:, 0]], archive.X[pairs[:, 1]], problem.xl, problem.xu, rng,
                                CROSSOVER_PROBABILITY, CROSSOVER_ETA)
        return polynomial_mutation(children, problem.xl, problem.xu, self._mutation_etas(n), 1.0, rng)

    def _refined_count(self, n: int) -> int:
        """How many of ``n`` archive offspring are refinement children: round(``constrained_refine`` × n) in a
        constrained run's late phase (``constrained_late_phase``) once the archive holds a feasible point, else 0
        (so the infeasible start, the search of the first half and unconstrained runs are unchanged)."""
        if not (self.constrained_refine and self._late_phase() and self.leader_archive.feasible):
            return 0
        return int(round(self.constrained_refine * n))

    def _refined_children(self, n: int) -> np.ndarray:
        """``n`` refinement children (``constrained_refine``): a local search around feasible archive members.

        Each child is an archive member with every variable moved by pymoo's polynomial mutation step of
        η = :data:`REFINE_ETA`, about 1 % of its range. A share :data:`REFINE_ENDS` of the members are the
        ends of the front (the minimum of each objective in turn), the others are drawn by the leader rule
        (on a full feasible archive NSGA-II's crowding tournament). Why (issue 33, fifth
        change, docs/MOPSO.md): on MW3, MW7, CTP2 and CTP3 the final archive was spread as evenly as
        NSGA-II's population but lay further from the front — near kinks and segment ends on constraint
        boundaries (MW7's lower branch after f1 ≈ 0.9, CTP2's first segment next to the f1 = 0 end, CTP3's
        isolated front points) — and a child of SBX between two distant members, or of a one-variable
        mutation, lands near such a member too rarely to move it closer.
        """
        archive, problem, rng = self.leader_archive, self.problem, self.random_state
        chosen = archive.select_leaders(n, rng, self.leader)
        # the first round(REFINE_ENDS n) refine the ends of the front instead, the objectives' minima in turn
        ends = int(round(REFINE_ENDS * n))
        chosen[:ends] = np.argmin(archive.F, axis=0)[np.arange(ends) % archive.F.shape[1]]
        return polynomial_steps(archive.X[chosen], problem.xl, problem.xu, np.full(n, REFINE_ETA), 1.0, rng)

    def _mutation_etas(self, n: int):
        """The polynomial mutation's distribution index for n rows (particles or archive offspring).

        ``mutation_eta``, except on a problem with constraints, where the first
        round(``constrained_fine_mutation`` × n) rows take NSGA-II's :data:`FINE_MUTATION_ETA` from the
        first generation on (issue 33, docs/MOPSO.md: the fronts lie on constraint boundaries, where the
        long-tailed steps mostly leave the feasible region; the redraw of ``constrained_reset`` makes the long
        jumps instead); in a constrained run's late phase (``constrained_late_phase``) every row takes
        :data:`LATE_FINE_ETA`. A scalar when all rows share one, so that unconstrained runs are unchanged.
        """
        if self._late_phase():
            return np.full(n, LATE_FINE_ETA)
        if not (self.constrained_fine_mutation and self.constrained_problem):
            return self.mutation_eta
        etas = np.full(n, float(self.mutation_eta))
        etas[:int(round(self.constrained_fine_mutation * n))] = FINE_MUTATION_ETA
        return etas

    def _reset_share(self) -> float:
        """The share of this generation's archive offspring redrawn by :func:`uniform_reset` (``constrained_reset``):
        the first share until the archive is feasible and full, the second from then on; 0 without constraints."""
        if not (self.constrained_reset and self.constrained_problem):
            return 0.0
        archive = self.leader_archive
        return self.constrained_reset[1] if archive.feasible and archive.filled else self.constrained_reset[0]

    def _late_phase(self) -> bool:
        """Whether this generation is in a constrained run's late phase (``constrained_late_phase``): the
        generations done, the initial swarm's not counted, reach that share of the planned ones
        (:meth:`_planned_generations`)."""
        if self.constrained_late_phase is None or not self.constrained_problem:
            return False
        return (self.n_iter - 1) / max(1, self.planned_generations - 1) >= self.constrained_late_phase

    def _exploring_share(self) -> float:
        """Share of the swarm that makes SMPSO's move (:func:`smpso_velocity`) this move.

        max(0, 1 − |A| / (``exploration`` × Z_ar)): 1 while the archive is empty, 0 once
        it holds ``exploration`` × ``archive_size`` members. A small archive is what a
        swarm stalled on a multimodal landscape shows (one local optimum dominates
        everything found so far: under the attraction-only update ZDT4's archive held one
        or two members from generation 17 to 49, docs/MOPSO.md), while on a front the swarm
        has reached the archive fills within a few generations and the velocity variant
        contracts the swarm as before.
        """
        if not self.exploration:
            return 0.0
        return max(0.0, 1.0 - len(self.leader_archive) / (self.exploration * self.archive_size))

    def _scheduled(self, value, move: int) -> float:
        """A coefficient at move ``move``: a constant, or a pair [start, end] linear from the
        first move (0) to the last planned one (planned generations − 2), then ``end``."""
        if not isinstance(value, tuple):
            return value
        start, end = value
        last = self.planned_generations - 2
        return end if last <= 0 else start + (end - start) * min(1.0, move / last)

    def _coello_mutation(self, X: np.ndarray, move: int) -> np.ndarray:
        """Coello 2004's mutation operator (§IV-C).

        With T = planned generations − 1 the number of moves in the run and t the index
        of this move (0-based), the operator is active while t < T p_m, with strength
        s = (1 − t / (T p_m))^1.5: each particle is mutated with probability s, in one
        dimension chosen at random, to a uniform value in [x − s Δ, x + s Δ] ∩ [xl, xu]
        (Δ = xu − xl). So at the start every particle is mutated over the full range, and
        both the share of mutated particles and the range shrink to 0 at t = T p_m. The
        paper gives the operator in words; the 1.5 decay exponent is that of the
        authors' C implementation. The velocity is left unchanged.

        pymoo has no such operator; the paper preset's bit-identical archive depends on
        this one's draws (one uniform per particle for the hit, one integer for the
        dimension, one uniform for the value), so it stays here.
        """
        horizon = (self.planned_generations - 1) * self.mutation_rate
        if horizon <= 0 or move >= horizon:
            return X
        strength = (1.0 - move / horizon) ** MUTATION_DECAY_EXPONENT
        rng, (xl, xu) = self.random_state, (self.problem.xl, self.problem.xu)
        n, n_var = X.shape
        hit = rng.random(n) < strength
        dim = rng.integers(n_var, size=n)
        span = strength * (xu[dim] - xl[dim])
        current = X[np.arange(n), dim]
        low, high = np.maximum(xl[dim], current - span), np.minimum(xu[dim], current + span)
        drawn = low + rng.random(n) * (high - low)
        X = X.copy()
        X[np.flatnonzero(hit), dim[hit]] = drawn[hit]
        return X

    def _planned_generations(self) -> int:
        """Generations the run is planned to last (the initial swarm counts as one).

        ``horizon`` if given; else the limit of a termination that *is* a
        MaximumGenerationTermination (``n_gen``) or MaximumFunctionCallTermination
        (``n_eval`` E → ⌈E / pop_size⌉). The limits nested inside combined criteria such
        as pymoo's default termination (1,000 generations or 100,000 evaluations, but
        usually ended much earlier by its tolerances) are not a run length and are not
        read; then, if anything depends on the run length, paper 000's M = 100 is
        assumed with a warning.
        """
        if self.horizon is not None:
            return self.horizon
        criterion = self.termination
        limit = None
        if isinstance(criterion, MaximumGenerationTermination):
            limit = criterion.n_max_gen
        elif isinstance(criterion, MaximumFunctionCallTermination) and criterion.n_max_evals is not None:
            limit = math.ceil(criterion.n_max_evals / self.pop_size)
        if limit is not None and math.isfinite(limit):
            return max(1, int(limit))
        scheduled = any(isinstance(value, tuple) for value in (self.w, self.c1, self.c2))
        if scheduled or (self.mutation == "coello" and self.mutation_rate is not None):
            warnings.warn("MOPSO: the termination is not an n_gen/n_eval limit and optimizer.horizon is "
                          f"not set; schedules assume {PAPER_MAX_ITERATIONS} generations "
                          "(paper 000, Table 2)", stacklevel=2)
        return PAPER_MAX_ITERATIONS


def _coefficient(name: str, value, default):
    """A coefficient >= 0, or a pair [start, end] of them (returned as a tuple); None → default."""
    if value is None:
        return default
    allowed = "a number >= 0 or a pair [start, end] of such numbers"
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
        pair = tuple(_coefficient(name, item, None) for item in value)
        if any(isinstance(item, tuple) for item in pair):
            raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
        return pair
    if isinstance(value, bool):
        raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}") from None
    if not (math.isfinite(number) and number >= 0.0):
        raise ConfigError(f"{name}={value!r} is out of range; allowed: {allowed}")
    return value if isinstance(value, float) else number


def _reset_shares(value) -> tuple[float, float] | None:
    """``constrained_reset`` checked: a share in [0, 1] (both phases) or a pair [until full, afterwards]; None: no redraw."""
    if value is None:
        return None
    name, allowed = "optimizer.constrained_reset", "a share in [0, 1], a pair [until full, afterwards] of them, or null"
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
        shares = tuple(_reset_shares(item) for item in value)
        if any(share is None or share[0] != share[1] for share in shares):
            raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
        return shares[0][0], shares[1][0]
    if isinstance(value, bool):
        raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
    share = check_in(name, value, Interval(0.0, 1.0))
    return share, share


def _integer_mask(problem) -> np.ndarray | None:
    """``problem.is_integer`` checked: None when absent or all False."""
    mask = getattr(problem, "is_integer", None)
    if mask is None:
        return None
    mask = np.asarray(mask)
    if mask.dtype != bool or mask.shape != (problem.n_var,):
        raise ConfigError(f"problem.is_integer has dtype {mask.dtype} and shape {mask.shape}; "
                          f"allowed: a boolean array of length n_var={problem.n_var}")
    if not mask.any():
        return None
    low, high = np.ceil(problem.xl[mask]), np.floor(problem.xu[mask])
    if np.any(low > high):
        raise ConfigError("problem.is_integer marks a variable whose bounds contain no integer; "
                          "allowed: integer variables with an integer in [xl, xu]")
    return mask

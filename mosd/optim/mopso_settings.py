"""The MOPSO's settings: the constants its options default to, paper 000's preset, and the checks of the options
that are more than a range or a choice (:class:`mosd.optim.mopso.MOPSO`'s constructor)."""
from __future__ import annotations

import math

import numpy as np

from ..validation import ConfigError, Interval, check_in

#: Coello 2004's inertia variant: W = 0.4 and unit acceleration coefficients.
COELLO_INERTIA = (0.4, 1.0, 1.0)
#: The default's coefficients: inertia 0.6 → 0.2 and social 1.75 → 1.0 over the run, cognitive 1.0
#: (chosen on ZDT1–3, a shifted ZDT1 and DTLZ2, docs/MOPSO.md).
SCHEDULED = ((0.6, 0.2), 1.0, (1.75, 1.0))
#: Velocity variants: which (w, c1, c2) an unset coefficient takes.
VELOCITIES = ("scheduled", "constriction", "inertia")
#: Iterations M of paper 000's Table 2: the run length assumed when nothing else tells it.
PAPER_MAX_ITERATIONS = 100
#: Personal-best update, see :meth:`MOPSO._update_personal_best`.
PERSONAL_BEST_RULES = ("dominance", "coin")
#: Mutation operators, see :meth:`MOPSO._infill`.
MUTATIONS = ("polynomial", "coello")
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



def coefficient(name: str, value, default):
    """A coefficient >= 0, or a pair [start, end] of them (returned as a tuple); None → default."""
    if value is None:
        return default
    allowed = "a number >= 0 or a pair [start, end] of such numbers"
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
        pair = tuple(coefficient(name, item, None) for item in value)
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


def reset_shares(value) -> tuple[float, float] | None:
    """``constrained_reset`` checked: a share in [0, 1] (both phases) or a pair [until full, afterwards]; None: no redraw."""
    if value is None:
        return None
    name, allowed = "optimizer.constrained_reset", "a share in [0, 1], a pair [until full, afterwards] of them, or null"
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
        shares = tuple(reset_shares(item) for item in value)
        if any(share is None or share[0] != share[1] for share in shares):
            raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
        return shares[0][0], shares[1][0]
    if isinstance(value, bool):
        raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
    share = check_in(name, value, Interval(0.0, 1.0))
    return share, share


def integer_mask(problem) -> np.ndarray | None:
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

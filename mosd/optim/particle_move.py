"""The particles' move of :class:`mosd.optim.mopso.MOPSO` (paper 000, eqs. 38–39) and their personal bests.

One move on NumPy arrays (or compiled, :mod:`mosd.optim.compiled_move`), Coello 2004's mutation, the archive
offspring in the last slots (:mod:`mosd.optim.offspring`), and the personal-best update after the evaluation. A
mixin of :class:`~mosd.optim.mopso.MOPSO`; every draw comes from the algorithm's ``random_state``.
"""
from __future__ import annotations

import numpy as np

from .archive import pairwise_dominates
from .mopso_settings import MUTATION_DECAY_EXPONENT
from .variation import apply_bounds, polynomial_mutation, round_integers, smpso_velocity


class ParticleMove:
    """Eqs. 38–39 for the swarm's particles (a mixin of :class:`~mosd.optim.mopso.MOPSO`)."""

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

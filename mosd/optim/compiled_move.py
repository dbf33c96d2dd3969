"""The compiled move's glue (:mod:`mosd.kernels.swarm`) for :class:`mosd.optim.mopso.MOPSO`.

When the kernels apply, the particles' move and the archive offspring's crossover and mutation are one compiled
call each, drawing from the algorithm's Generator through :func:`mosd.kernels.swarm.bit_source`: the same
arithmetic and draws as the NumPy code of :mod:`mosd.optim.particle_move` and :mod:`mosd.optim.offspring`
(``tests/test_kernel_swarm.py`` compares the two within a stated tolerance). A mixin of
:class:`~mosd.optim.mopso.MOPSO`.
"""
from __future__ import annotations

import math

import numpy as np

from .. import kernels
from .variation import BOUNDARY_RULES, SMPSO_C_RANGE, SMPSO_INERTIA, SMPSO_MAX_VELOCITY

#: an empty array: no velocity clamp, or no distribution indices, for the compiled move (never written to)
_NO_LIMIT = np.empty(0)


class CompiledMove:
    """Whether and how the compiled move runs (a mixin of :class:`~mosd.optim.mopso.MOPSO`)."""

    def _compiled_move(self):
        """The compiled move (:mod:`mosd.kernels.swarm`) when it applies, else None (then the NumPy code of
        :mod:`mosd.optim.particle_move` and :mod:`mosd.optim.offspring` runs).

        It applies when the kernels are on, the random state is a NumPy Generator, the boundary rule is one of
        :func:`~mosd.optim.variation.apply_bounds`' and the particles' mutation is polynomial or none (Coello's
        stays NumPy code); on an empty cache, from the generation its compilation ahead ends
        (:func:`mosd.kernels.swarm.ready`).
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
        """The particles' move of :meth:`~mosd.optim.particle_move.ParticleMove._particles` in one call of
        :func:`mosd.kernels.swarm.particle_move`."""
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

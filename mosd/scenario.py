"""Scenario = plant + noise + fault: simulates a batch of closed-loop replications."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .fault import SensorFault
from .noise import GaussianNoise
from .types import Trace
from .validation import ConfigError, Interval, check_in, check_int

#: Seed streams: the replications of one role never share draws with another's.
STREAMS = {"calibration": 0, "training": 1, "test": 2}


def replication_rngs(seed: int, stream: str | int, n_reps: int, first: int = 0) -> list[np.random.Generator]:
    """Independent generators for replications ``first .. first+n_reps-1`` of a stream.

    Replication r of (seed, stream) always gets the same generator, however the
    replications are batched or distributed over workers.
    """
    sid = STREAMS[stream] if isinstance(stream, str) else int(stream)
    return [np.random.default_rng([int(seed), sid, r]) for r in range(first, first + n_reps)]


class Scenario:
    """A plant in closed loop with its noise and (optionally) one sensor fault.

    Parameters
    ----------
    plant : MouldOscillator or compatible
        Provides ``f``, ``h``, ``initial_state``, ``controller`` and ``dt``.
    noise : GaussianNoise or compatible
        Provides ``draw(rng, n_samples) -> (w, v)``.
    fault : SensorFault, optional
        None simulates the fault-free plant.
    duration : float
        Simulated time in s (the trace has round(duration/dt) samples).
    """

    def __init__(self, plant, noise: GaussianNoise, fault: SensorFault | None = None, duration: float = 5.2):
        self.plant, self.noise, self.fault = plant, noise, fault
        self.duration = check_in("scenario.duration", duration, Interval(0.0, 1e6, open_low=True))
        self.n_samples = int(round(self.duration / plant.dt))
        if self.n_samples < 2:
            raise ConfigError(f"scenario.duration={duration} gives fewer than 2 samples; allowed: >= 2*dt")
        if fault is not None and fault.channel >= len(plant.output_names):
            raise ConfigError(
                f"fault.channel={fault.channel} is out of range; allowed: 0..{len(plant.output_names) - 1}"
            )

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.n_samples) * self.plant.dt

    def simulate(
        self, seed: int, n_reps: int, stream: str | int = "training", fault_scale: float = 1.0, first: int = 0
    ) -> Trace:
        """Simulate ``n_reps`` independent replications in one vectorised loop.

        Order within sample k: y_k = h(x_k) + v_k (+ g_k); the controller maps
        y_k to u_k; x_{k+1} = f(x_k, u_k) + w_k. ``fault_scale`` is σ of the
        faulty channel's residual (see :mod:`mosd.fault`).
        """
        n_reps = check_int("n_reps", n_reps, 1)
        t = self.time
        N = self.n_samples
        plant = self.plant
        rngs = replication_rngs(seed, stream, n_reps, first)
        draws = [self.noise.draw(rng, N) for rng in rngs]
        w = np.stack([d[0] for d in draws])  # (R, N, n_x)
        v = np.stack([d[1] for d in draws])  # (R, N, n_y)
        n_y = v.shape[-1]
        g = np.zeros((n_reps, N, n_y))
        mask = np.zeros((n_reps, N), dtype=bool)
        if self.fault is not None:
            for r, rng in enumerate(rngs):
                g[r, :, self.fault.channel] = self.fault.signal(t, fault_scale, rng)
            mask[:] = self.fault.active(t)
        controller = plant.controller()
        controller.reset(n_reps)
        x = np.empty((n_reps, N, len(plant.state_names)))
        y = np.empty((n_reps, N, n_y))
        u = np.empty((n_reps, N, len(plant.input_names)))
        xk = np.broadcast_to(plant.initial_state(), (n_reps, x.shape[-1])).copy()
        for k in range(N):
            x[:, k] = xk
            yk = plant.h(xk) + v[:, k] + g[:, k]
            y[:, k] = yk
            uk = controller(yk)
            u[:, k] = uk
            xk = plant.f(xk, uk) + w[:, k]
        meta = {
            "seed": int(seed),
            "stream": stream,
            "first_replication": int(first),
            "fault": repr(self.fault),
            "fault_scale": float(fault_scale),
            "output_names": tuple(plant.output_names),
            "dt": plant.dt,
        }
        return Trace(t=t, u=u, x=x, y=y, fault_mask=mask, meta=meta)

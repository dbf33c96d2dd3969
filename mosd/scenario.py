"""Scenario = plant + noise + fault(s): simulates a batch of seeded replications."""
from __future__ import annotations


from dataclasses import replace

import numpy as np

from .types import SensorSamples, Trace
from .validation import ConfigError, Interval, check_in, check_int

#: Seed streams: the replications of one role never share draws with another's.
STREAMS = {"calibration": 0, "training": 1, "test": 2, "estimator": 3}


def replication_rngs(seed: int, stream: str | int, n_reps: int, first: int = 0) -> list[np.random.Generator]:
    """Independent generators for replications ``first .. first+n_reps-1`` of a stream.

    Replication r of (seed, stream) always gets the same generator, however the
    replications are batched or distributed over workers.
    """
    sid = STREAMS[stream] if isinstance(stream, str) else int(stream)
    return [np.random.default_rng([int(seed), sid, r]) for r in range(first, first + n_reps)]


#: The replication of the ``estimator`` stream whose generator trains an estimator (its initial
#: weights, shuffling, particles): far beyond any simulated training run of that stream.
TRAINING_REPLICATION = 2**31


def training_rng(seed: int) -> np.random.Generator:
    """The generator an estimator's ``fit`` draws from: replication :data:`TRAINING_REPLICATION`
    of the ``estimator`` stream of ``seed`` (the simulated training runs are replications 0, 1, …)."""
    return replication_rngs(seed, "estimator", 1, first=TRAINING_REPLICATION)[0]


class Scenario:
    """A plant with its noise and (optionally) a fault or a set of faults.

    Parameters
    ----------
    plant : mosd.plants.base.Plant
    noise : noise model of :mod:`mosd.noise` accepted by the plant
    fault : mosd.faults.base.Fault, optional
        None simulates the fault-free plant. A :class:`~mosd.faults.base.FaultSet`
        gives replication r its member ``r mod n`` (labels 1..n in the trace).
    duration : float
        Simulated time in s (the trace has round(duration/dt) samples).
    """

    def __init__(self, plant, noise, fault=None, duration: float = 5.2):
        self.plant, self.noise, self.fault = plant, noise, fault
        self.duration = check_in("scenario.duration", duration, Interval(0.0, 1e6, open_low=True))
        self.n_samples = int(round(self.duration / plant.dt))
        if self.n_samples < 2:
            raise ConfigError(f"scenario.duration={duration} gives fewer than 2 samples; allowed: >= {2 * plant.dt:g} "
                              f"(2 samples of dt={plant.dt:g})")
        if fault is not None:
            for member in fault.members:
                plant.check_fault(member)
                if member.onset >= self.duration:
                    raise ConfigError(f"fault.onset={member.onset:g} is past the end of the run "
                                      f"(scenario.duration={self.duration:g}); allowed: 0 <= onset < duration")

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.n_samples) * self.plant.dt

    def simulate(
        self, seed: int, n_reps: int, stream: str | int = "training", fault_scale: float | None = None, first: int = 0
    ) -> Trace:
        """Simulate replications ``first .. first+n_reps-1`` of a seed stream.

        ``fault_scale`` is the unit of relative faults (σ of the faulty
        channel's fault-free residual, see :mod:`mosd.faults.sensor`): required
        for one (no default unit is right; :meth:`mosd.experiment.Experiment.simulate`
        computes it), ignored by absolute faults.
        """
        n_reps = check_int("n_reps", n_reps, 1)
        rngs = replication_rngs(seed, stream, n_reps, first)
        meta = {"seed": int(seed), "stream": stream, "first_replication": int(first)}
        if self.fault is None:
            trace = self.plant.simulate(self.n_samples, self.noise, None, rngs, fault_scale)
            return replace(trace, fault_mask=np.zeros_like(trace.fault_mask), fault_label=None, fault_roles=(),
                           meta={**trace.meta, **meta})
        members = self.fault.members
        roles = tuple(m.role for m in members)
        groups = [[i for i in range(n_reps) if (first + i) % len(members) == j] for j in range(len(members))]
        parts = []
        for j, (member, idx) in enumerate(zip(members, groups)):
            if not idx:
                continue
            trace = self.plant.simulate(self.n_samples, self.noise, member, [rngs[i] for i in idx], fault_scale)
            label = np.where(trace.fault_mask, j + 1, 0).astype(np.int8)
            parts.append((idx, replace(trace, fault_label=label, fault_mask=trace.fault_mask & (member.role == "target"))))
        trace = parts[0][1] if len(parts) == 1 else _merge(parts, n_reps)
        return replace(trace, fault_roles=roles, meta={**trace.meta, **meta, "fault": repr(self.fault)})


def _merge(parts: list[tuple[list[int], Trace]], n_reps: int) -> Trace:
    """One trace from groups of replications simulated separately (replication order restored)."""
    first = parts[0][1]

    def gather(get, pad=np.nan):
        arrays = [np.asarray(get(t)) for _, t in parts]
        width = max(a.shape[1] for a in arrays) if arrays[0].ndim > 1 else None
        out = None
        for (idx, _), a in zip(parts, arrays):
            if out is None:
                out = np.full((n_reps,) + ((width,) + a.shape[2:] if width is not None else a.shape[1:]), pad,
                              dtype=a.dtype)
            out[idx, : a.shape[1]] = a
        return out

    sensors = {name: SensorSamples(t=gather(lambda t, n=name: t.sensors[n].t),
                                   y=gather(lambda t, n=name: t.sensors[n].y),
                                   arrived=gather(lambda t, n=name: t.sensors[n].arrived, pad=False))
               for name in first.sensors}
    return Trace(t=first.t, u=gather(lambda t: t.u), x=gather(lambda t: t.x), y=gather(lambda t: t.y),
                 fault_mask=gather(lambda t: t.fault_mask, pad=False), meta=dict(first.meta),
                 fault_label=gather(lambda t: t.fault_label, pad=0), sensors=sensors)

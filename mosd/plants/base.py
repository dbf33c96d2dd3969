"""The plant contract: simulate a batch of replications and describe yourself to an estimator.

A plant has its parameters in ``__init__`` and two verbs:

* :meth:`Plant.simulate` — ``n_samples`` samples of every replication, one
  seeded generator per replication (so a replication's draws never depend on
  how replications are batched), with the noise model's draws and the fault's
  signal injected where the physics puts them (a sensor, an actuator, the state);
* :meth:`Plant.model` — what an estimator may assume about the plant, given the
  noise model (a :class:`~mosd.model.StateSpaceModel` for the cubature filters;
  another plant may return what its estimator needs).

:class:`ClosedLoopPlant` is the discrete-time loop y_k = h(x_k) + v_k (+ g_k),
u_k = controller(y_k), x_{k+1} = f(x_k, u_k) + w_k with an additive sensor fault
g_k (``fault_targets = ("sensor",)``); plants of that form (paper 000's mould oscillator) implement f, h, the
initial state and the controller and inherit ``simulate``.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..faults.sensor import sensor_fault_signals, unit_of
from ..types import Trace
from ..validation import Component, ConfigError


class Plant(Component):
    """Base class of every plant (module docstring)."""

    config_group = "plant"
    dt: float
    state_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    #: where ``simulate`` injects a fault (values of :data:`mosd.faults.base.ACTS_ON`); check_fault refuses the rest
    fault_targets: tuple[str, ...] = ("sensor",)

    def simulate(self, n_samples: int, noise, fault, rngs: Sequence[np.random.Generator],
                 fault_scale: float | None = None) -> Trace:
        """``len(rngs)`` replications of ``n_samples`` samples (``fault`` None: fault-free).

        ``fault_scale`` is the unit of a relative fault (σ of the faulty channel's fault-free
        residual: :meth:`mosd.experiment.Experiment.fault_scale`); a relative fault without it is
        refused (:func:`mosd.faults.sensor.unit_of`), an absolute fault ignores it.
        """
        raise NotImplementedError

    def model(self, noise) -> Any:
        """What an estimator assumes about this plant under ``noise``."""
        raise NotImplementedError

    def check_fault(self, fault) -> None:
        """Raise ConfigError when ``fault`` (or a member of a fault set) cannot act on this plant.

        Follows from two declarations: the fault's ``acts_on`` (:mod:`mosd.faults.base`) must be one
        of this plant's ``fault_targets``, and the channel (sensor) or actuator it names must be one of
        ``output_names`` or ``input_names``. A plant with more to check (an onset on its grid)
        extends this method.
        """
        for member in getattr(fault, "members", (fault,)):
            acts_on = getattr(member, "acts_on", "")
            if acts_on not in self.fault_targets:
                raise ConfigError(_wrong_target(self, member, acts_on))
            if acts_on == "sensor" and not 0 <= member.channel < len(self.output_names):
                raise ConfigError(f"fault.channel={member.channel} is out of range; "
                                  f"allowed: 0..{len(self.output_names) - 1} ({', '.join(self.output_names)})")
            if acts_on == "actuator" and not 1 <= member.actuator <= len(self.input_names):
                raise ConfigError(f"fault.actuator={member.actuator} is out of range; allowed: "
                                  f"1..{len(self.input_names)} ({', '.join(self.input_names)})")


def check_fault_class(plant: Plant, fault_class: type) -> None:
    """Refuse a fault class that cannot act on ``plant`` before its parameters are read.

    A preset's keys for its own fault (two_tank's ``fault.channel``) do not fit another fault class; the
    reason to give is then where the fault acts, not a key the user never wrote (:meth:`Plant.check_fault`
    checks the built fault's channel or actuator afterwards).
    """
    acts_on = getattr(fault_class, "acts_on", None)
    if isinstance(acts_on, str) and acts_on and acts_on not in plant.fault_targets:
        raise ConfigError(_wrong_target(plant, fault_class.__name__, acts_on))


def fault_classes(targets: Sequence[str]) -> list[str]:
    """Names of the fault classes of :mod:`mosd.faults` that act on one of ``targets`` (found, not listed)."""
    from .. import faults
    from ..faults.base import Fault

    found = (getattr(faults, name) for name in faults.__all__)
    return sorted(cls.__name__ for cls in found
                  if isinstance(cls, type) and issubclass(cls, Fault) and cls.acts_on in targets)


def _wrong_target(plant: Plant, fault, acts_on: str) -> str:
    """The one line refusing ``fault`` on ``plant``: where it acts, where the plant takes faults, which fit."""
    name = type(plant).__module__.rpartition(".")[2]
    phrase = {"sensor": "a sensor", "actuator": "an actuator", "state": "the state"}
    where = f"acts on {phrase.get(acts_on, repr(acts_on))}" if acts_on else "declares no acts_on"
    classes = ", ".join(fault_classes(plant.fault_targets)) or "none"
    label = fault if isinstance(fault, str) else repr(fault)
    return (f"fault={label} {where}, but plant {name} takes faults acting on "
            f"{' or '.join(plant.fault_targets)} only; "
            f"allowed: {classes} (`mosd options fault` lists each option's acts_on)")


class ClosedLoopPlant(Plant):
    """A discrete-time plant in closed loop with an additive sensor fault (module docstring).

    Subclasses provide ``f(x, u)``, ``h(x)`` (both broadcasting over a leading
    replication axis), ``initial_state()``, ``controller()`` (with ``reset(n_reps)``
    and ``__call__(y) -> u``) and the name tuples; the noise model provides
    ``draw(rng, n_samples) -> (w, v)``; the fault ``signal(t, scale, rng)``.
    """

    fault_targets = ("sensor",)  # the loop adds g_k to the measured outputs only

    def simulate(self, n_samples: int, noise, fault, rngs: Sequence[np.random.Generator],
                 fault_scale: float | None = None) -> Trace:
        """Order within sample k: y_k = h(x_k) + v_k (+ g_k); the controller maps y_k to u_k;
        x_{k+1} = f(x_k, u_k) + w_k. ``fault_scale`` is σ of the faulty channel's fault-free residual."""
        n_reps, N = len(rngs), int(n_samples)
        t = np.arange(N) * self.dt
        draws = [noise.draw(rng, N) for rng in rngs]
        w = np.stack([d[0] for d in draws])  # (R, N, n_x)
        v = np.stack([d[1] for d in draws])  # (R, N, n_y)
        n_y = v.shape[-1]
        g, mask = sensor_fault_signals(fault, t, rngs, n_y, fault_scale)
        controller = self.controller()
        controller.reset(n_reps)
        compiled = self._compiled_loop(controller)
        if compiled is not None:
            x, y, u = compiled(np.asarray(self.initial_state(), float), v, g, w)
        else:
            x = np.empty((n_reps, N, len(self.state_names)))
            y = np.empty((n_reps, N, n_y))
            u = np.empty((n_reps, N, len(self.input_names)))
            xk = np.broadcast_to(self.initial_state(), (n_reps, x.shape[-1])).copy()
            for k in range(N):
                x[:, k] = xk
                yk = self.h(xk) + v[:, k] + g[:, k]
                y[:, k] = yk
                uk = controller(yk)
                u[:, k] = uk
                xk = self.f(xk, uk) + w[:, k]
        meta = {"fault": repr(fault), "fault_scale": unit_of(fault, fault_scale), "output_names": tuple(self.output_names),
                "dt": self.dt}
        return Trace(t=t, u=u, x=x, y=y, fault_mask=mask, meta=meta)

    def _compiled_loop(self, controller):
        """A compiled form of the loop above for this plant and controller, or None (the default).

        It must return the loop's x, y, u bit for bit: ``(x0, v, g, w) -> (x, y, u)``.
        """
        return None

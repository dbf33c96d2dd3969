"""Paper 001's Figs. 2–5 as ours: mode probabilities, amplitude, and RMSE fused vs. each sensor.

Hu, Jin, Xue and Sun (2017) show, over 500 Monte Carlo runs of the turning
target with an actuator-2 fault f = 2 from 16.5 s: the normal model dominant
before the fault and the actuator-2 model above 0.5 soon after (Fig. 2), the
amplitude estimate (Fig. 3), and the state and amplitude RMSE of the fused
filter below those of sensor 1 < sensor 2 < sensor 3 (Figs. 4–5). The
computation here (docs/systems/paper001.md, a reconstruction) runs
:class:`~mosd.plants.networked_target.NetworkedTarget`, estimates with
:class:`~mosd.estimators.async_imm.AsyncIMMFusion` on all sensors and on each
one alone, and decides with
:class:`~mosd.detectors.mode_probability.ModeProbabilityDetector`. Everything
returned is plain dicts, lists and floats.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..detectors.mode_probability import ModeProbabilityDetector
from ..estimators.async_imm import AsyncIMMFusion
from ..faults.actuator import ActuatorFault
from ..metrics.estimation import rmse_over_runs
from ..metrics.registry import per_run
from ..monitors.outputs import OutputMonitor
from ..noise.continuous import ContinuousWhiteNoise
from ..plants.networked_target import NetworkedTarget
from ..scenario import Scenario

DURATION = 41.0  # fusion instants t = 0, 1, ..., 40 s
FILTERS = {"fused": None, "s1": ("s1",), "s2": ("s2",), "s3": ("s3",)}
#: the scenario's only fault (label 1) is the model set's fault 2 (actuator 2)
LABELS = (2, 1)
DESIGNS = ((0.5, 1), (0.5, 2), (0.5, 3), (0.7, 1), (0.7, 2), (0.9, 1))


def scenario(faulty: bool = True) -> Scenario:
    """The paper's example: actuator 2 fails with f = 2 at 16.5 s (or no fault)."""
    return Scenario(NetworkedTarget(), ContinuousWhiteNoise(), ActuatorFault() if faulty else None, duration=DURATION)


def rmse_study(seed: int = 2017, n_reps: int = 500) -> dict:
    """Figs. 2–5: per filter, RMSE curves of the state and of the fault input, and their means over t = 1..40.

    Also the fused filter's mean mode probabilities (Fig. 2) and the mean
    amplitude estimate of the actuator-2 model per filter (Fig. 3).
    """
    sc = scenario()
    trace = sc.simulate(seed, n_reps, "test")
    model = sc.plant.model(sc.noise)
    out = {"t": trace.t.tolist(), "filters": {}}
    for name, sensors in FILTERS.items():
        res = AsyncIMMFusion(sensors=sensors).estimate(trace, model)
        state = rmse_over_runs(res.extra["x_filt"], trace.x[..., :2])
        fault = rmse_over_runs(res.extra["fault_estimate"], trace.x[..., 2:])
        out["filters"][name] = {
            "state_rmse": state.tolist(), "fault_rmse": fault.tolist(),
            "state_rmse_mean": float(state[1:].mean()), "fault_rmse_mean": float(fault[1:].mean()),
            "amplitude_mean": res.extra["fault_amplitudes"][..., 1].mean(axis=0).tolist(),
            "mode_probabilities_mean": res.extra["mode_probabilities"].mean(axis=0).tolist(),
        }
    return out


def detection_table(seed: int = 2017, n_reps: int = 500,
                    designs: Sequence[tuple[float, int]] = DESIGNS) -> list[dict]:
    """The decision rule (§4) for designs (μ_T, L): false alarms on faulty and fault-free runs, delay, isolation."""
    sc = scenario()
    model = sc.plant.model(sc.noise)
    estimator, monitor = AsyncIMMFusion(), OutputMonitor(outputs=["mode_probabilities"])
    faulty = monitor.transform(estimator.estimate(sc.simulate(seed, n_reps, "test"), model))
    clean = monitor.transform(estimator.estimate(scenario(False).simulate(seed, n_reps, "calibration"), model))
    detector = ModeProbabilityDetector(labels=LABELS)
    X = np.asarray(designs, float)
    on_faulty = detector.population(None, faulty.z, X).decision
    on_clean = detector.population(None, clean.z, X).decision
    rows = []
    for (mu_T, L), d, d0 in zip(designs, on_faulty, on_clean):
        rows.append({
            "mu_T": float(mu_T), "L": int(L),
            "far": float(per_run("far", d, faulty).mean()),
            "far_fault_free": float(per_run("far", d0, clean).mean()),
            "alarmed_fault_free_runs": float(np.mean((d0 != 0).any(axis=-1))),
            "delay": float(np.nanmean(per_run("delay", d, faulty))),
            "detection_rate": float(np.nanmean(per_run("detection_rate", d, faulty))),
            "isolation_rate": float(np.nanmean(per_run("isolation_rate", d, faulty))),
        })
    return rows

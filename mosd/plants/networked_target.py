"""Paper 001's plant: a target on a circle, observed by asynchronous sensors over a lossy network.

Hu, Jin, Xue, Sun, "Fault diagnosis of networked systems based on asynchronous
IMM fusion filtering", Acta Automatica Sinica 43(8), 2017 (paper 001). Its
equations and matrices were lost in extraction; this module is the
reconstruction documented in ``docs/systems/paper001.md``:

* continuous-time linear plant (reconstruction of eq. 1 and §5)::

      ẋ = A x + B (u + e_m f) + w,   A = ω [[0, −1], [1, 0]],  B = I₂,  E[w(t) w(s)ᵀ] = Q_c δ(t − s)

  fault-free it moves on a circle about −A⁻¹ B u (the text: "uniform circular
  motion at a fixed angular speed" with a constant u); an actuator fault of
  amplitude f shifts the centre.
* N sensors (reconstruction of eqs. 2–3): sensor n samples at
  t⁽ⁿ⁾_1 = first_samples[n], t⁽ⁿ⁾_{l+1} = t⁽ⁿ⁾_l + T⁽ⁿ⁾_l with T⁽ⁿ⁾_l fixed or drawn
  uniformly from a set; z = H x(t) + v, v ~ N(0, R); the packet reaches the
  fusion centre with probability β⁽ⁿ⁾, independently of everything else
  (the paper's assumption 2).
* the fusion centre works at t_k = k T (``dt`` = the fusion period T).

The state is simulated exactly (matrix exponential, Van Loan) on a grid of step
``resolution``; every sample instant and the fault onset must lie on that grid,
which keeps the simulation exact and vectorised over replications. The
estimator (:mod:`mosd.estimators.async_imm`) makes no such assumption: it takes
arbitrary sample instants.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from scipy.linalg import expm

from ..noise.continuous import psd_sqrt
from ..types import SensorSamples, Trace
from ..validation import ConfigError, Interval, Param, check_in
from .base import Plant

_POSITIVE = Interval(0.0, math.inf, open_low=True)
_GRID_TOL = 1e-9


@dataclass(frozen=True)
class SensorModel:
    """One sensor of a linear model: z = H x + v, v ~ N(0, R)."""

    name: str
    H: np.ndarray
    R: np.ndarray


@functools.lru_cache(maxsize=4096)
def _discretised(A: bytes, B: bytes, Q: bytes, n: int, n_u: int, delta: float):
    """:meth:`ContinuousLinearModel.discretise` of one interval, from the model's matrices as bytes (a pure
    function, memoised: Φ, Γ and Q_d depend on A, B, Q_c and Δ only). Read-only arrays."""
    A = np.frombuffer(A).reshape(n, n)
    B = np.frombuffer(B).reshape(n, n_u)
    Q = np.frombuffer(Q).reshape(n, n)
    with_input = np.zeros((n + n_u, n + n_u))
    with_input[:n, :n], with_input[:n, n:] = A, B
    ex = expm(delta * with_input)
    phi, gamma = ex[:n, :n], ex[:n, n:]
    van_loan = np.zeros((2 * n, 2 * n))
    van_loan[:n, :n], van_loan[:n, n:], van_loan[n:, n:] = -A, Q, A.T
    q = phi @ expm(delta * van_loan)[:n, n:]
    parts = (np.ascontiguousarray(phi), np.ascontiguousarray(gamma), 0.5 * (q + q.T))
    for part in parts:
        part.flags.writeable = False
    return parts


@dataclass(frozen=True)
class ContinuousLinearModel:
    """What the networked plant tells an estimator: ẋ = A x + B u + w, sensors z = H x + v.

    Attributes
    ----------
    A : ndarray (n, n)
    B : ndarray (n, n_u)
    u : ndarray (n_u,)
        The known, constant command.
    process_intensity : ndarray (n, n)
        Q_c of the white process noise.
    sensors : tuple of SensorModel
    x0, P0 : ndarray (n,), (n, n)
        Prior mean and covariance of x(0).
    dt : float
        Fusion period T (s).
    fault_directions : ndarray (n, d_f)
        Column m−1 is the direction B e_m in which fault m enters ẋ (paper 001, §2).
    """

    A: np.ndarray
    B: np.ndarray
    u: np.ndarray
    process_intensity: np.ndarray
    sensors: tuple[SensorModel, ...]
    x0: np.ndarray
    P0: np.ndarray
    dt: float
    fault_directions: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def n_x(self) -> int:
        return self.A.shape[0]

    @property
    def sensor_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    def discretise(self, delta) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact discretisation over intervals ``delta`` (any shape, each >= 0).

        Returns Φ = e^{AΔ} (..., n, n), Γ = ∫₀^Δ e^{As} ds B (..., n, n_u) and
        Q_d = ∫₀^Δ e^{As} Q_c e^{Aᵀs} ds (..., n, n), so that
        x(t + Δ) = Φ x(t) + Γ u + w_d with w_d ~ N(0, Q_d) for a constant input
        over the interval. Φ and Γ come from one exponential of [[A, B], [0, 0]]Δ;
        Q_d from Van Loan's exponential of [[−A, Q_c], [0, Aᵀ]]Δ (Van Loan 1978).
        """
        delta = np.asarray(delta, float)
        # the same few intervals recur across estimators, studies and replications (paper 001's study: 13,423
        # intervals in 1,573 calls, 34 distinct): each distinct one is discretised once per model, one matrix at a
        # time as SciPy's batched expm computes each of its matrices, so the values are those of one batched call
        values, inverse = np.unique(delta, return_inverse=True)
        key = (*(np.ascontiguousarray(m, float).tobytes() for m in (self.A, self.B, self.process_intensity)),
               self.A.shape[0], self.B.shape[1])
        parts = [_discretised(*key, float(value)) for value in values]
        return tuple(np.stack([part[i] for part in parts])[inverse.reshape(delta.shape)] for i in range(3))

    def augment(self, direction: np.ndarray, intensity: float, variance: float) -> "ContinuousLinearModel":
        """The model with an unknown amplitude f appended to the state (paper 001, eqs. 15–19, reconstructed).

        z = [x; f], ż = [[A, d], [0, 0]] z + [B; 0] u + [w; w_f] with
        E[w_f w_fᵀ] = ``intensity`` δ (f a random walk: constant or slowly
        varying amplitude), prior f ~ N(0, ``variance``), sensors H' = [H, 0].
        ``direction`` d = 0 gives the paper's normal model m = 0, whose f has
        "no physical meaning" and only unifies the form.
        """
        n = self.n_x
        A = np.zeros((n + 1, n + 1))
        A[:n, :n], A[:n, n] = self.A, np.asarray(direction, float)
        Q = np.zeros((n + 1, n + 1))
        Q[:n, :n], Q[n, n] = self.process_intensity, intensity
        P0 = np.zeros((n + 1, n + 1))
        P0[:n, :n], P0[n, n] = self.P0, variance
        sensors = tuple(replace(s, H=np.hstack([s.H, np.zeros((s.H.shape[0], 1))])) for s in self.sensors)
        return replace(self, A=A, B=np.vstack([self.B, np.zeros((1, self.B.shape[1]))]), process_intensity=Q,
                       sensors=sensors, x0=np.append(self.x0, 0.0), P0=P0,
                       fault_directions=np.zeros((n + 1, 0)))


def _sequence(key: str, value) -> tuple:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) == 0:
        raise ConfigError(f"{key}={value!r} is not allowed; allowed: a non-empty list with one entry per sensor")
    return tuple(value)


def _vector(key: str, value, size: int) -> np.ndarray:
    try:
        arr = np.asarray(value, float)
    except (TypeError, ValueError):
        arr = np.empty(0)
    if arr.shape != (size,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{key}={value!r} is not allowed; allowed: a list of {size} finite numbers")
    return arr


def _period_choices(key: str, value) -> tuple[float, ...]:
    """A sensor's period: one number, or a non-empty list of numbers drawn from uniformly."""
    choices = tuple(value) if hasattr(value, "__len__") and not isinstance(value, str) else (value,)
    if not choices:
        raise ConfigError(f"{key} has an empty list; allowed: a period > 0 or a non-empty list of them")
    return tuple(check_in(key, p, _POSITIVE) for p in choices)


def _per_sensor(entry):
    """A ``Param`` validator: a non-empty list, one entry per sensor, each checked by ``entry``
    (an Interval or a function ``(key, value) -> value``)."""
    def check(key, value, plant):
        values = _sequence(key, value)
        if isinstance(entry, Interval):
            return tuple(check_in(key, v, entry) for v in values)
        return tuple(entry(key, v) for v in values)
    return check


class NetworkedTarget(Plant):
    """A target turning at rate ω, observed by asynchronous networked sensors (paper 001, §5; reconstruction).

    ``Trace.t`` is the fusion grid t_k = k T, k = 0..N−1 (t_0 carries the prior).
    ``Trace.x`` holds the true state at t_k followed by the true fault input of
    each actuator (columns ``f1``, ``f2``, ...: the amplitudes an estimator
    estimates). ``Trace.y`` is empty; the measurements are in
    ``Trace.sensors[name]`` (``"s1"``, ``"s2"``, ...), with their instants and
    whether each packet arrived. Accepts :class:`~mosd.faults.actuator.ActuatorFault`
    and :class:`~mosd.noise.continuous.ContinuousWhiteNoise`.
    """

    params = {
        "omega": Param(Interval(-10.0, 10.0), "Turn rate ω (rad/s) (paper: 0.2)."),
        "u": Param(lambda key, value, plant: _vector(key, value, 2), "Constant command (paper: [0.5, 0.5]).",
                   kind="sequence of 2 floats"),
        "fusion_period": Param(Interval(0.0, 100.0, open_low=True), "T (s) of the fusion centre (paper: 1)."),
        "resolution": Param(Interval(0.0, "fusion_period", open_low=True), "Simulation grid step (s); sample "
                            "instants, periods, the fusion period and fault onsets must be multiples of it."),
        "initial_state": Param(lambda key, value, plant: _vector(key, value, 2), "x(0), also the estimator's prior "
                               "mean (reconstruction: 0).", kind="sequence of 2 floats"),
        "initial_cov": Param(_POSITIVE, "Prior covariance P_0 = initial_cov·I of the estimator (reconstruction: 1)."),
        "first_samples": Param(_per_sensor(_POSITIVE), "First sample instant of each sensor (s) (paper: 0.2, 0.3, "
                               "0.4).", kind="sequence of float > 0"),
        "periods": Param(_per_sensor(_period_choices), "Per sensor: a period (s) or a list of periods drawn "
                         "uniformly and independently for every sample (paper: 0.6, 0.6, [0.8, 0.9, 1.0]).",
                         kind="sequence of float > 0 or of lists of them"),
        "arrival": Param(_per_sensor(Interval(0.0, 1.0)), "Per sensor: packet arrival probability β (paper: 0.9, "
                         "0.8, 0.8).", kind="sequence of float in [0, 1]"),
    }

    state_names = ("x1", "x2")
    input_names = ("u1", "u2")
    output_names = ("x1", "x2")
    fault_targets = ("actuator",)  # f e_m is added to the command u (ActuatorFault)

    def __init__(
        self,
        omega: float = 0.2,
        u: Sequence[float] = (0.5, 0.5),
        fusion_period: float = 1.0,
        first_samples: Sequence[float] = (0.2, 0.3, 0.4),
        periods: Sequence = (0.6, 0.6, (0.8, 0.9, 1.0)),
        arrival: Sequence[float] = (0.9, 0.8, 0.8),
        initial_state: Sequence[float] = (0.0, 0.0),
        initial_cov: float = 1.0,
        resolution: float = 0.1,
    ):
        self._assign(locals())
        self.dt = self.fusion_period
        n_sensors = len(self.first_samples)
        if not len(self.periods) == len(self.arrival) == n_sensors:
            raise ConfigError(f"plant.first_samples, plant.periods and plant.arrival have lengths {n_sensors}, "
                              f"{len(self.periods)}, {len(self.arrival)}; allowed: one entry per sensor each")
        self._check_on_grid("plant.fusion_period", [self.fusion_period])
        self._check_on_grid("plant.first_samples", self.first_samples)
        self._check_on_grid("plant.periods", [p for choices in self.periods for p in choices])

    @property
    def sensor_names(self) -> tuple[str, ...]:
        return tuple(f"s{n + 1}" for n in range(len(self.first_samples)))

    def _check_on_grid(self, key: str, values) -> None:
        for value in values:
            steps = value / self.resolution
            if abs(steps - round(steps)) > _GRID_TOL * max(1.0, steps):
                raise ConfigError(f"{key}: {value:g} is not a multiple of plant.resolution={self.resolution:g}; "
                                  f"allowed: multiples of plant.resolution")

    def check_fault(self, fault) -> None:
        """An actuator fault on an existing actuator (Plant.check_fault), with the onset on the simulation grid."""
        super().check_fault(fault)
        for member in getattr(fault, "members", (fault,)):
            self._check_on_grid("fault.onset", [member.onset])

    def model(self, noise) -> ContinuousLinearModel:
        """The continuous-time model with every sensor's H = I₂ and the noise model's Q_c and R."""
        _check_noise(noise)
        A = self.omega * np.array([[0.0, -1.0], [1.0, 0.0]])
        B = np.eye(2)
        R = np.asarray(noise.measurement_cov, float)
        sensors = tuple(SensorModel(name, np.eye(2), R) for name in self.sensor_names)
        return ContinuousLinearModel(A=A, B=B, u=self.u.copy(), process_intensity=np.asarray(
            noise.process_intensity, float), sensors=sensors, x0=self.initial_state.copy(),
            P0=self.initial_cov * np.eye(2), dt=self.fusion_period, fault_directions=B.copy())

    def simulate(self, n_samples: int, noise, fault, rngs: Sequence[np.random.Generator],
                 fault_scale: float | None = None) -> Trace:
        """Exact simulation of ``len(rngs)`` replications over ``n_samples`` fusion instants.

        Per replication, the generator draws, in this order: the process noise
        of every grid step, then per sensor its random periods (if any), its
        measurement noise and its packet arrivals; so a replication's draws never
        depend on how replications are batched. ``fault_scale`` is ignored
        (actuator faults are absolute). ``fault`` may also be a list with one
        fault (or None) per replication, simulated in one batch (paper 001's
        calibration runs, whose faults start at random instants:
        :func:`mosd.systems.paper001.mode_calibration`).
        """
        model = self.model(noise)
        n_reps, n_x = len(rngs), model.n_x
        t = np.arange(int(n_samples)) * self.fusion_period
        n_grid = int(round(t[-1] / self.resolution)) + 1
        grid = np.arange(n_grid) * self.resolution
        phi, gamma, q = model.discretise(self.resolution)
        if isinstance(fault, (list, tuple)):
            fault_input, drive, mask = self._each_replication(fault, n_reps, grid, t, gamma)
        else:  # one fault for every replication: its arrays, broadcast
            fault_input, drive, mask = (np.broadcast_to(a, (n_reps,) + a.shape)
                                        for a in self._fault_drive(fault, grid, t, gamma))
        process = np.stack([rng.standard_normal((n_grid - 1, n_x)) for rng in rngs]) @ psd_sqrt(q).T
        x = np.empty((n_reps, n_grid, n_x))
        x[:, 0] = self.initial_state
        for g in range(n_grid - 1):
            x[:, g + 1] = x[:, g] @ phi.T + drive[:, g] + process[:, g]
        sensors = {name: self._sample(n, x, grid, model.sensors[n], rngs) for n, name in enumerate(self.sensor_names)}
        on_fusion_grid = np.rint(t / self.resolution).astype(int)
        truth = np.concatenate([x[:, on_fusion_grid], fault_input[:, on_fusion_grid]], axis=-1)
        meta = {"fault": repr(fault), "dt": self.fusion_period, "resolution": self.resolution,
                "state_names": self.state_names + tuple(f"f{i + 1}" for i in range(len(self.input_names))),
                "sensor_names": self.sensor_names}
        return Trace(t=t, u=np.broadcast_to(self.u, (n_reps, t.size, self.u.size)).copy(), x=truth,
                     y=np.empty((n_reps, t.size, 0)), fault_mask=mask.copy(), meta=meta, sensors=sensors)

    def _each_replication(self, faults, n_reps: int, grid: np.ndarray, t: np.ndarray, gamma: np.ndarray):
        """Fault input, drive and fault mask of each replication from a list of one fault (or None) per replication;
        each distinct fault's drive computed as a lone fault's is."""
        if len(faults) != n_reps:
            raise ConfigError(f"fault: a list of {len(faults)} faults for {n_reps} replications; allowed: one fault "
                              f"(or None) per replication")
        fault_input = np.zeros((n_reps, grid.size, len(self.input_names)))
        drive = np.empty((n_reps, grid.size, gamma.shape[0]))
        mask = np.zeros((n_reps, t.size), bool)
        done: dict = {}
        for r, fault in enumerate(faults):
            key = None if fault is None else (fault.actuator, repr(fault))
            if key not in done:
                done[key] = self._fault_drive(fault, grid, t, gamma)
            fault_input[r], drive[r], mask[r] = done[key]
        return fault_input, drive, mask

    def _fault_drive(self, fault, grid: np.ndarray, t: np.ndarray, gamma: np.ndarray):
        """One fault's (or None's) input on the grid, the drive it gives, and its mask on the fusion instants."""
        fault_input = np.zeros((grid.size, len(self.input_names)))
        if fault is not None:
            self.check_fault(fault)
            fault_input[:, fault.actuator - 1] = fault.signal(grid)
        drive = (self.u + fault_input) @ gamma.T  # input held over [t_g, t_g + resolution)
        return fault_input, drive, fault.active(t) if fault is not None else np.zeros(t.shape, bool)

    def _sample(self, n: int, x: np.ndarray, grid: np.ndarray, sensor: SensorModel,
                rngs: Sequence[np.random.Generator]) -> SensorSamples:
        """Sensor n's instants, measurements and packet arrivals over the simulated horizon."""
        horizon, choices = grid[-1], self.periods[n]
        n_slots = int(math.floor((horizon - self.first_samples[n]) / min(choices) + _GRID_TOL)) + 1
        if n_slots < 1:
            empty = np.empty((len(rngs), 0))
            return SensorSamples(t=empty, y=np.empty((len(rngs), 0, sensor.H.shape[0])), arrived=empty.astype(bool))
        m = sensor.H.shape[0]
        steps, noise, arrived = [], [], []
        for rng in rngs:
            steps.append(choices[0] * np.ones(n_slots - 1) if len(choices) == 1 else
                         rng.choice(np.asarray(choices), size=n_slots - 1))
            noise.append(rng.standard_normal((n_slots, m)))
            arrived.append(rng.random(n_slots) < self.arrival[n])
        times = self.first_samples[n] + np.concatenate([np.zeros((len(rngs), 1)), np.cumsum(steps, axis=1)], axis=1)
        times = np.rint(times / self.resolution) * self.resolution  # no drift off the grid from summed periods
        inside = times <= horizon + _GRID_TOL
        index = np.minimum(np.rint(times / self.resolution).astype(int), grid.size - 1)
        state = np.take_along_axis(x, index[..., None], axis=1)
        y = state @ sensor.H.T + np.stack(noise) @ psd_sqrt(sensor.R).T
        return SensorSamples(t=np.where(inside, times, np.nan), y=np.where(inside[..., None], y, np.nan),
                             arrived=np.stack(arrived) & inside)


def _check_noise(noise) -> None:
    if not (hasattr(noise, "process_intensity") and hasattr(noise, "measurement_cov")):
        raise ConfigError(f"noise={type(noise).__name__} is not accepted by plant networked_target; "
                          f"allowed: ContinuousWhiteNoise (process_intensity, measurement_cov)")

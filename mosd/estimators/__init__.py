"""Estimators and residual generators (the contract in :mod:`.base`); one module per family."""
from ..exports import lazy
from .base import Estimator
from .cubature import CESCKF, CubatureKalmanFilter, EmbeddedCubatureRule, FilterResult, SphericalRadialRule
from .residuals import DedicatedObserverResidual, InnovationResidual

#: the other components of the kind, imported on first use (mosd.exports)
_LAZY = {
    "AsyncIMMFusion": "async_imm",
    "AltitudeKalmanFilter": "ekf",
    "EntropyIsolationFilter": "entropy_filter",
    "FixedGainFilter": "entropy_filter",
    "MeasuredSignals": "measured",
    "MultiStepNeuralObserver": "neural_observer",
    "PCAResidual": "pca",
}
__getattr__, __dir__, __all__ = lazy(__name__, _LAZY, [
    "CESCKF", "CubatureKalmanFilter", "DedicatedObserverResidual", "EmbeddedCubatureRule", "Estimator",
    "FilterResult", "InnovationResidual", "SphericalRadialRule",
])

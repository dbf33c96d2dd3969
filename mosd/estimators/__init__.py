"""Estimators and residual generators (the contract in :mod:`.base`); one module per family."""
from .base import Estimator
from .cubature import CESCKF, CubatureKalmanFilter, EmbeddedCubatureRule, FilterResult, SphericalRadialRule
from .residuals import DedicatedObserverResidual, InnovationResidual

__all__ = [
    "CESCKF", "CubatureKalmanFilter", "DedicatedObserverResidual", "EmbeddedCubatureRule", "Estimator",
    "FilterResult", "InnovationResidual", "SphericalRadialRule",
]

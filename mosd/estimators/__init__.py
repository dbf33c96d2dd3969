"""Estimators and residual generators (the contract in :mod:`.base`); one module per family, exported by
existing (:mod:`mosd.exports`)."""
from ..exports import lazy
from .base import Estimator
from .cubature import CESCKF, CubatureKalmanFilter, EmbeddedCubatureRule, FilterResult, SphericalRadialRule
from .residuals import DedicatedObserverResidual, InnovationResidual

#: every module's components, found by a scan of the sources and imported on first use (mosd.exports)
__getattr__, __dir__ = lazy(__name__, globals())

"""mosd — residual-based fault detection with multi-objective tuning of the detector.

The science core (plants, noise, faults, estimators, monitor, charts, denoising,
metrics, ARL, optimisers) imports neither Hydra nor MLflow; those live in
:mod:`mosd.app` only (docs/ARCHITECTURE.md).
"""

__version__ = "0.1.0"

"""A latent family on a subgroup monitor's windows deploys (issue 28): a point holds n rows of one channel,
so the detector's stage reads n values per point, not one per stream column."""
from types import SimpleNamespace

import numpy as np
import pytest

from mosd.app.deploy import deployable
from mosd.detectors.pca import PCADetector
from mosd.experiment import first_replication
from mosd.monitors.subgroups import SubgroupMonitor
from mosd.types import Residuals


@pytest.mark.parametrize("flatline", [None, 0.3])
def test_pca_on_windows_streams_the_run_s_own_decisions(flatline):
    rng = np.random.default_rng(11)
    r = rng.standard_normal((3, 400, 1))
    r[:, 250:, 0] = 1.8 * r[:, 250:, 0] + 1.0
    outputs = Residuals(r=r, fault_mask=np.zeros(r.shape[:2], bool), channels=("c",), extra={})
    calibration = Residuals(r=rng.standard_normal((4, 400, 1)), fault_mask=np.zeros((4, 400), bool),
                            channels=("c",), extra={})
    monitor = SubgroupMonitor(subgroup="window", n=5, channels=[0], burn_in=20).fit(calibration)
    calibration_z = monitor.transform(calibration).z
    z = monitor.transform(outputs).z
    assert z.shape[-1] == 5
    detector = PCADetector(n_components=2, alpha=0.01, lam=0.5, persistence=1, flatline=flatline)
    decided = detector.decide(calibration_z, z)
    estimator = SimpleNamespace(online=lambda model: None, residual_columns=lambda o: ("residual_c",))
    setup = SimpleNamespace(experiment=SimpleNamespace(estimator=estimator, monitor=monitor, model=None))
    result = SimpleNamespace(detector=detector, example={"calibration_z": calibration_z,
                                                         "first_outputs": first_replication(outputs),
                                                         "decision": decided.decision[0]})
    found = deployable(setup, result)
    assert found.reason is None and found.pipeline is not None, found.reason
    assert found.pipeline.inputs == ("residual_c",)
    assert decided.decision[0].any() and not decided.decision[0].all()
    stream = found.pipeline.update({"residual_c": r[0, :, 0]})
    assert np.array_equal(stream["decision"] if "decision" in stream else stream["alarm"],
                          found.stream["decision" if "decision" in stream else "alarm"])

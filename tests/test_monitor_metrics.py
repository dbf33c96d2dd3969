import numpy as np
import pytest

from mosd.metrics import (DetectionReport, Estimate, detection_accuracy, detection_delay, false_alarm_rate,
                          missed_detection_rate)
from mosd.monitors import SubgroupMonitor as Monitor
from mosd.types import Residuals
from mosd.validation import ConfigError


def _residuals(r, onset=None):
    mask = np.zeros(r.shape[:2], bool)
    if onset is not None:
        mask[:, onset:] = True
    return Residuals(r=r, fault_mask=mask, channels=tuple(f"c{i}" for i in range(r.shape[-1])))


def test_window_subgroups_standardise_with_phase1_statistics():
    rng = np.random.default_rng(0)
    phase1 = _residuals(3.0 + 0.5 * rng.standard_normal((4, 1010, 2)))
    mon = Monitor(subgroup="window", n=5, channels=[1], burn_in=10).fit(phase1)
    assert mon.channel_std(1) == pytest.approx(0.5, rel=0.03)
    data = _residuals(3.0 + 0.5 * rng.standard_normal((2, 1010, 2)), onset=510)
    sub = mon.transform(data)
    assert sub.z.shape == (2, 200, 5)
    # subgroup k covers samples burn_in + 5k .. +4; faulty from subgroup 100 on
    assert not sub.fault_mask[:, :100].any() and sub.fault_mask[:, 100:].all()
    np.testing.assert_allclose(sub.z[1, 3], (data.r[1, 25:30, 1] - mon.mean_[0]) / mon.std_[0])


def test_channel_subgroups_are_the_residual_vector():
    rng = np.random.default_rng(1)
    phase1 = _residuals(rng.standard_normal((3, 300, 3)) * [1.0, 2.0, 3.0])
    mon = Monitor(subgroup="channels", channels=[0, 1, 2], burn_in=0).fit(phase1)
    sub = mon.transform(phase1)
    assert sub.z.shape == (3, 300, 3)
    np.testing.assert_allclose(sub.z.reshape(-1, 3).std(axis=0, ddof=1), 1.0, rtol=1e-12)


def test_monitor_validation():
    with pytest.raises(ConfigError, match="monitor.n"):
        Monitor(n=1)
    with pytest.raises(ConfigError, match="monitor.channels"):
        Monitor(subgroup="window", channels=[0, 1])
    with pytest.raises(ConfigError, match="monitor.subgroup"):
        Monitor(subgroup="rows")
    faulty = _residuals(np.ones((1, 20, 1)), onset=5)
    with pytest.raises(ConfigError, match="fault-free"):
        Monitor(burn_in=0).fit(faulty)


def test_rates_on_a_hand_made_sequence():
    mask = np.array([False] * 5 + [True] * 5)
    alarms = np.array([0, 1, 0, 0, 0, 0, 0, 1, 1, 1], bool)
    assert false_alarm_rate(alarms, mask) == pytest.approx(0.2)
    assert missed_detection_rate(alarms, mask) == pytest.approx(0.4)
    assert detection_accuracy(alarms, mask) == pytest.approx(0.4)
    assert detection_delay(alarms, mask) == 2
    assert np.isnan(detection_delay(np.zeros(10, bool), mask))
    batch = np.stack([alarms, ~alarms])
    np.testing.assert_allclose(false_alarm_rate(batch, mask), [0.2, 0.8])


def test_report_summary_confidence_interval():
    rng = np.random.default_rng(2)
    mask = np.zeros((200, 50), bool)
    mask[:, 25:] = True
    alarms = rng.random((200, 50)) < 0.3
    s = DetectionReport.of(alarms, mask).summary()
    assert s["far"].mean == pytest.approx(0.3, abs=0.02)
    assert s["mdr"].mean == pytest.approx(0.7, abs=0.02)
    # 95 % t interval of 200 replications of a binomial(25, 0.3)/25 share
    assert s["far"].half_width == pytest.approx(1.97 * np.sqrt(0.21 / 25) / np.sqrt(200), rel=0.15)
    assert Estimate.of([1.0]).n == 1 and np.isnan(Estimate.of([]).mean)

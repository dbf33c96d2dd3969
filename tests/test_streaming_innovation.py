"""The paper's innovation residual (estimator=innovation, eq. 7) streams raw measurements and inputs too: the same
causal stage as the dedicated observer with no channel left out of the update (issue 28)."""
from __future__ import annotations

import numpy as np

from mosd.estimators.cubature import CESCKF
from mosd.estimators.residuals import InnovationResidual
from mosd.estimators.step import EstimatorStage
from mosd.streaming import OnlinePipeline

from test_streaming import check_chunks  # one call == chunks of 1, 2, 5, 13 rows
from test_streaming_cesckf import PLANT, RAW, _residuals, _scenario, _stage


def test_the_innovation_streams_the_batch_innovations_in_any_chunks():
    scenario = _scenario(0.2)
    trace = scenario.simulate(3, 3, stream="test", fault_scale=1.0)
    first = scenario.simulate(3, 1, stream="test", fault_scale=1.0)
    estimator = InnovationResidual(filter=CESCKF())
    model, stage = _stage(estimator, first)
    assert isinstance(stage, EstimatorStage) and stage.estimator == "mosd.estimators.residuals.InnovationResidual"
    batch = estimator.estimate(trace, model).r[0]
    columns = estimator.raw_stream(first, model, PLANT.input_names)
    assert tuple(columns) == RAW and stage.inputs == RAW
    whole = check_chunks(OnlinePipeline([stage]), columns)
    r = _residuals(whole, model)
    assert np.array_equal(r, batch)
    # every channel updates the filter: the offset is partly absorbed, unlike the dedicated observer's residual
    fault_rows = first.fault_mask[0]
    assert abs(r[fault_rows, 0].mean()) > 2 * abs(r[~fault_rows, 0].mean())


def test_a_saved_innovation_stage_loads_as_the_innovation(tmp_path):
    first = _scenario(0.1).simulate(3, 1, stream="test", fault_scale=1.0)
    model, stage = _stage(InnovationResidual(), first)
    pipeline = OnlinePipeline([stage])
    pipeline.save(tmp_path)
    loaded = OnlinePipeline.load(tmp_path / OnlinePipeline.FILE)
    columns = InnovationResidual().raw_stream(first, model, PLANT.input_names)
    a, b = pipeline.update(columns), loaded.update(columns)
    assert all(np.array_equal(a[k], b[k]) for k in a)

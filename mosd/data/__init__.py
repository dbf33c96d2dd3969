"""Recorded data as a system: named, disjoint splits instead of seed streams (the contract in :mod:`.base`).

:class:`~mosd.data.tep.TennesseeEastman` reads the Braatz TE files, :class:`~mosd.data.table.Table` any
labelled CSV/Parquet export; :class:`mosd.recorded.RecordedExperiment` runs the pipeline on them. One module per
source, exported by existing (:mod:`mosd.exports`).
"""
from ..exports import lazy
from .base import SPLITS, RecordedData, Segment

#: every module's sources, found by a scan of the sources and imported on first use (mosd.exports)
__getattr__, __dir__ = lazy(__name__, globals())

"""Recorded data as a system: named, disjoint splits instead of seed streams (the contract in :mod:`.base`).

:class:`~mosd.data.tep.TennesseeEastman` reads the Braatz TE files, :class:`~mosd.data.table.Table` any
labelled CSV/Parquet export; :class:`mosd.recorded.RecordedExperiment` runs the pipeline on them.
"""
from .base import SPLITS, RecordedData, Segment

__all__ = ["RecordedData", "SPLITS", "Segment"]

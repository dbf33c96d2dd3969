"""The file a fitted model (:mod:`mosd.app.detector_model`, :mod:`mosd.app.chart_model`) is saved in and loaded from.

One ``.npz`` file per model: its arrays, and its scalar design as JSON under ``meta``; read
without pickles, so loading a model runs no code from the file. Written whole or not at all
(:func:`mosd.app.atomic.write_atomically`), like every other file of a run: a full disk leaves
the previous file or none, never one cut short that ``mosd log`` would then upload.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

import numpy as np

from .atomic import write_atomically


def save_arrays(path: Path, meta: Mapping, **arrays: np.ndarray) -> Path:
    """A fitted model's arrays and its scalar design (``meta``, as JSON) in one ``.npz`` file (no pickles)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_atomically(path, lambda out: np.savez(out, meta=np.array(json.dumps(meta)), **arrays), binary=True)


def read_arrays(path: str | Path, file_name: str) -> tuple[dict[str, np.ndarray], dict]:
    """What :func:`save_arrays` wrote, from its file or the directory holding ``file_name``: (arrays, meta)."""
    path = Path(path)
    if path.is_dir():
        path = path / file_name
    with np.load(path, allow_pickle=False) as f:
        return {k: f[k] for k in f.files if k != "meta"}, json.loads(str(f["meta"]))

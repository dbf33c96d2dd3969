"""Each row's top contributing tags of a PCA: what the served stage adds to T² and SPE (``top_t2``, ``top_spe``).

:func:`mosd.detectors.pca.stream_scores` ranks the contributions in the compiled one-pass scoring, or, on the
NumPy path, with :func:`top_indices` per block of rows; :func:`top_labels` names the ranked tags.
"""
from __future__ import annotations

import numpy as np

#: variables named per row in ``top_t2`` / ``top_spe``
TOP = 3


def top_indices(model, a: int, Z: np.ndarray, name: str, out: np.ndarray, cache: dict) -> np.ndarray:
    """Indices of the :data:`TOP` largest contributions per standardised row of Z (0 where missing), largest
    first; ``out`` (rows, m) is scratch.

    T²: c_i = z_i (Pₐ Λₐ⁻¹ Pₐᵀ z)_i; SPE: c_i = e_i², e = (I − Pₐ Pₐᵀ) z
    (:meth:`mosd.detectors.pca.PCAModel.contributions`), each one product with an (m, m) matrix made once per model and component count.
    """
    key = ("maps", id(model), a)
    maps = cache.get(key)
    if maps is None or maps[0] is not model:
        P = np.asarray(model.loadings, float)
        maps = cache[key] = (model, {"t2": (P[:, :a] / np.asarray(model.eigenvalues)[:a]) @ P[:, :a].T,
                                     "spe": np.eye(len(P)) - P[:, :a] @ P[:, :a].T})
    c = np.matmul(Z, maps[1][name], out=out)
    if name == "t2":
        c *= Z
    else:
        c *= c
    return _largest(c, TOP)


def _largest(c: np.ndarray, k: int) -> np.ndarray:
    """Column indices of the k largest values of every row of c, largest first (c is overwritten)."""
    rows = np.arange(len(c))
    out = np.empty((len(c), min(k, c.shape[1])), np.intp)
    for j in range(out.shape[1]):
        out[:, j] = winner = np.argmax(c, axis=1)
        if j + 1 < out.shape[1]:
            c[rows, winner] = -np.inf
    return out


def top_labels(index: np.ndarray, finite: np.ndarray, tags: tuple, cache: dict) -> np.ndarray:
    """``tag;tag;tag`` per row of (n, TOP) indices, largest first ('' where the row is not scored): each
    combination joined once (a few hundred in a file), then looked up in a table of every combination
    (kept in ``cache`` per tuple of tags)."""
    m, k = len(tags), index.shape[1]
    code = np.zeros(len(index), np.int64)
    for j in range(k):
        code = code * m + index[:, j]
    if m**k > 1 << 20:  # too many combinations for a table: join each distinct one of this block
        unique, inverse = np.unique(code, return_inverse=True)
        joined = [";".join(tags[(c // m**(k - 1 - j)) % m] for j in range(k)) for c in unique.tolist()]
        out = np.array(joined, dtype=object)[inverse.reshape(-1)]
    else:
        table = cache.get(("labels", tags, k))
        if table is None:
            table = cache[("labels", tags, k)] = (np.full(m**k, None, dtype=object), np.zeros(m**k, bool))
        labels, filled = table
        for c in np.unique(code[~filled[code]]).tolist():
            parts, rest = [], c
            for _ in range(k):
                rest, j = divmod(rest, m)
                parts.append(tags[j])
            labels[c], filled[c] = ";".join(reversed(parts)), True
        out = labels[code]
    if not finite.all():
        out[~finite] = ""      # a fancy-indexed copy: the table is not touched
    return out

"""Paper 000's numbers (data, not code): its tables, its faults' names and the methods it compares.

The comparison charts' designs (Table 3's λ and K_SD) and Table 4's design are recorded
designs (``mosd/systems/designs/paper000.json``); the faults are ``conf/fault/<name>.yaml``
(§3.3: a = b = 2 in units of the in-control residual σ). ``tests/test_paper.py`` checks that
the designs file and :data:`PAPER_TABLE3` agree.
"""
from __future__ import annotations

from ..base import recorded_designs

#: The three simulated faults of §3.3, named as their ``conf/fault`` options.
FAULTS = ("offset", "variance", "offset_var")
FAULT_LABELS = {"offset": "offset a = 2", "variance": "variance b = 2", "offset_var": "offset + variance a = b = 2"}

_RECORDED = recorded_designs("paper000")
#: Fixed parameters of the comparison charts, paper 000 Table 3 (λ and K_SD columns;
#: MS-OEWMA's width is its L), by method and fault.
PAPER_PRESETS: dict[str, dict[str, dict[str, float]]] = _RECORDED["paper"]

#: Paper 000 Table 3: (MDR %, FAR %, λ, K_SD) per method and fault.
PAPER_TABLE3: dict[str, dict[str, tuple[float, float, float, float]]] = {
    "M-DEWMA": {"offset": (1.4, 0.0, 0.4, 1.5), "variance": (15.0, 18.4, 0.3, 0.2),
                "offset_var": (17.0, 17.2, 0.3, 0.3)},
    "MS-OEWMA": {"offset": (0.0, 2.2, 0.3388, 4.8621), "variance": (19.8, 0.0, 0.3388, 4.8621),
                 "offset_var": (15.2, 6.2, 0.3388, 4.8621)},
    "SS-DEWMA": {"offset": (1.2, 0.0, 0.4, 3.0), "variance": (14.0, 9.6, 0.3, 0.15),
                 "offset_var": (14.8, 8.8, 0.3, 0.2)},
    "MO-SS-DEWMA": {"offset": (0.0, 0.2, 0.3247, 3.4703), "variance": (8.4, 5.2, 0.3214, 0.1415),
                    "offset_var": (7.8, 6.2, 0.3030, 0.2158)},
}

#: Paper 000 Table 4: the design optimised on offset+variance data, (λ, K_SD), and its
#: (MDR %, FAR %) on each fault.
PAPER_TABLE4_PARAMS: dict[str, float] = _RECORDED["table4"]
PAPER_TABLE4: dict[str, tuple[float, float]] = {
    "offset": (0.0, 1.4),
    "variance": (8.8, 5.4),
    "offset_var": (7.8, 6.2),
}

#: Fig. 1 / §2.3: after optimisation MDR and FAR were below 1 % for
#: λ ∈ [0.25, 0.45], K_SD ∈ [3.5, 5] (offset fault).
PAPER_GOOD_REGION = {"lam": (0.25, 0.45), "K": (3.5, 5.0), "below": 0.01}

#: MOPSO search box of Table 2 (K_SD ∈ (0, 5); λ keeps its open (0, 1)); the preset's ``detector.bounds``.
PAPER_BOUNDS = {"K": (0.0, 5.0)}

METHODS = ("M-DEWMA", "MS-OEWMA", "SS-DEWMA", "MO-SS-DEWMA")
#: The extra row: MS-OEWMA with its own tuning rule on our training data.
TUNED_MS_OEWMA = "MS-OEWMA (tuned)"
#: The causal counterpart of MO-SS-DEWMA: tuned the same way on the raw (undenoised) statistic.
CAUSAL_OURS = "MO-SS-DEWMA, causal"
BASELINES = ("M-DEWMA", "MS-OEWMA", "SS-DEWMA")


def paper_error_bound(fault: str) -> float:
    """FAR + MDR of the paper's MO-SS-DEWMA for ``fault`` (Table 3), as a rate."""
    mdr, far, _, _ = PAPER_TABLE3["MO-SS-DEWMA"][fault]
    return (mdr + far) / 100.0

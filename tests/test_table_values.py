"""Issue 53 item 8: valid data is not refused or changed silently.

A tag in units of 1e-14 was called constant and dropped (an absolute floor on its spread) while one scaled by 1e140
ran; a column named twice was renamed ``TI-0.1`` by pandas and monitored as another tag.
"""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from mosd.data.table import Table
from mosd.validation import ConfigError


def _frame(n=600, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, 3)) @ rng.standard_normal((3, 3))
    frame = pd.DataFrame(x, columns=["a", "b", "c"])
    frame.insert(0, "fault", 0)
    frame.loc[400:440, "fault"] = 1
    frame.loc[500:540, "fault"] = 1
    return frame


@pytest.mark.parametrize("scale", [1e-14, 1.0, 1e140])
def test_a_tag_is_constant_by_its_own_scale_not_an_absolute_floor(tmp_path, scale):
    frame = _frame()
    frame["b"] *= scale
    frame["flat"] = 0.0888  # a real constant: its std is rounding noise, about 1e-17
    frame.to_csv(tmp_path / "t.csv", index=False)
    table = Table(tmp_path / "t.csv", label_column="fault")
    assert table.output_names == ("a", "b", "c") and table.dropped == ("flat",)


def test_a_column_named_twice_is_refused_in_one_line(tmp_path):
    path = tmp_path / "dup.csv"
    path.write_text("fault,TI-0,TI-0,FI-1\n" + "".join(f"0,{i % 7},{i % 5},{i % 3}\n" for i in range(300)))
    with pytest.raises(ConfigError, match=r"column 'TI-0' is named twice \(again at position 2\); allowed") as info:
        Table(path, label_column="fault")
    assert "\n" not in str(info.value)


def test_iso_times_whose_offset_changes_at_dst_are_one_clock(tmp_path):
    """Before: 'row 0 holds '2024-03-31T01:00:00+01:00', not a time' (Europe's spring change, +01:00 -> +02:00)."""
    utc = pd.date_range("2024-03-31T00:00:00Z", periods=600, freq="60s")
    local = utc.tz_convert("Europe/Berlin")
    frame = _frame()
    frame.insert(0, "time", [t.isoformat() for t in local])
    assert frame["time"].str.endswith("+01:00").any() and frame["time"].str.endswith("+02:00").any()
    frame.to_csv(tmp_path / "dst.csv", index=False)
    table = Table(tmp_path / "dst.csv", time_column="time", label_column="fault")
    assert table.dt == pytest.approx(60.0)
    # a column mixing stamps with and without an offset has no one clock: still refused, naming the row
    frame.loc[5, "time"] = "2024-03-31T00:05:00"
    frame.to_csv(tmp_path / "mixed.csv", index=False)
    with pytest.raises(ConfigError, match=r"column 'time' row 0 holds .* not a time"):
        Table(tmp_path / "mixed.csv", time_column="time", label_column="fault")

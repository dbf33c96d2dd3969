"""The Tennessee Eastman loader and the recorded-data contract (mosd.data.tep, mosd.data.base).

Oracles: the raw files parsed by np.loadtxt here, and bibmon's own loader where its file
names are right (test ids 0..21, training ids 0 and 10..21; docs/systems/tep.md).
"""
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from mosd.data.base import Segment
from mosd.data.tep import (DEFAULT_FAULTS, ONSET, PRESETS, VARIABLES, TennesseeEastman, bibmon_directory,
                           file_name)
from mosd.validation import ConfigError

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def te():
    return TennesseeEastman(variables="all")


@pytest.fixture(scope="module")
def folder():
    found = bibmon_directory()
    assert found is not None, 'bibmon is a test dependency (pip install ".[test]")'
    return found


def test_file_names_are_two_digit_not_bibmons():
    assert [file_name(i) for i in (0, 1, 9, 10, 21)] == ["d00.dat", "d01.dat", "d09.dat", "d10.dat", "d21.dat"]
    assert file_name(3, test=True) == "d03_te.dat"


def test_d00_is_transposed_and_every_file_has_the_braatz_shape(te, folder):
    raw = np.loadtxt(folder / "d00.dat")
    assert raw.shape == (52, 500)  # stored one variable per row
    np.testing.assert_array_equal(te.raw("d00.dat"), raw.T)
    for n in range(22):
        assert te.raw(file_name(n, test=True)).shape == (960, 52)
        if n:
            assert te.raw(file_name(n)).shape == (480, 52)


def test_training_file_of_fault_1_is_d01_not_d10(te, folder):
    """bibmon 1.2.0 builds 'd1.dat' and pads it to 'd10.dat': fault 10's data for fault 1. mosd must not."""
    d01, d10 = np.loadtxt(folder / "d01.dat"), np.loadtxt(folder / "d10.dat")
    np.testing.assert_array_equal(te.raw("d01.dat"), d01)
    assert not np.allclose(te.raw("d01.dat"), d10)
    training = te.segments("training")
    first = training[0]
    assert (first.source, first.label) == ("d01.dat", 1)
    # end to end: the training split's first run is rows 0-159 of the file d01.dat itself
    np.testing.assert_array_equal(te.trace("training").y[0], d01[:160])
    every = TennesseeEastman(variables="all", faults=range(1, 22))
    training = every.trace("training")
    for fault in range(1, 10):  # the ids bibmon gets wrong
        run = [r for r, seg in enumerate(every.segments("training")) if seg.label == fault][0]
        np.testing.assert_array_equal(training.y[run], np.loadtxt(folder / f"d0{fault}.dat")[:160])


def test_agrees_with_bibmon_where_its_file_names_are_right(te):
    import bibmon  # a test dependency: a missing one fails, never skips
    for train_id, test_id in ((0, 0), (10, 1), (13, 5), (21, 21)):
        train_df, test_df = bibmon.load_tennessee_eastman(train_id, test_id)
        assert list(train_df.columns) == list(VARIABLES)
        np.testing.assert_allclose(te.raw(file_name(train_id)), train_df.to_numpy(), rtol=0, atol=1e-12)
        np.testing.assert_allclose(te.raw(file_name(test_id, test=True)), test_df.to_numpy(), rtol=0, atol=1e-12)
    # where bibmon's training name is wrong, it returns another fault's file (or fails): documented, not copied
    train_df, _ = bibmon.load_tennessee_eastman(1, 1)
    if np.allclose(train_df.to_numpy(), te.raw("d10.dat")):
        assert not np.allclose(train_df.to_numpy(), te.raw("d01.dat"))  # bibmon's mistake is still there


def test_splits_are_disjoint_and_shaped_as_documented():
    te = TennesseeEastman()
    assert te.output_names == PRESETS["literature"] and len(te.output_names) == 33
    cal, train, test = te.trace("calibration"), te.trace("training"), te.trace("test")
    # d00.dat and the lead-ins of d02_te ... d20_te; not d00_te.dat's, whose rows 160-959 give the test FAR (issue 49)
    assert cal.y.shape == (11, 500, 33) and cal.x.shape == (11, 500, 0) and cal.u.shape[-1] == 0
    assert np.isfinite(cal.y[0]).all() and np.isfinite(cal.y[1:, :ONSET]).all() and np.isnan(cal.y[1:, ONSET:]).all()
    assert not cal.fault_mask.any()
    assert train.y.shape == (3 * len(DEFAULT_FAULTS) + 11, 160, 33)
    assert train.fault_mask[: 3 * len(DEFAULT_FAULTS)].all() and not train.fault_mask[3 * len(DEFAULT_FAULTS):].any()
    assert test.y.shape == (19, 800, 33)  # by default the training faults, then d00_te
    np.testing.assert_array_equal(test.fault_label.max(axis=1), list(DEFAULT_FAULTS) + [0])
    assert test.fault_mask[:18].all() and not test.fault_mask[18].any()
    # rows 160..959 of d05_te.dat, variables in the literature's order
    np.testing.assert_array_equal(test.y[3], te.raw("d05_te.dat")[ONSET:][:, te._columns])
    every = TennesseeEastman(test_faults=range(1, 22)).trace("test")
    np.testing.assert_array_equal(every.fault_label.max(axis=1), list(range(1, 22)) + [0])
    rows = {}
    for split, segments in te.describe().items():
        assert segments
        for seg in te.segments(split):
            taken = rows.setdefault(seg.source, np.zeros(960, int))
            taken[seg.start:seg.stop] += 1
    assert max(v.max() for v in rows.values()) == 1  # no row in two splits
    assert te.describe()["test"][-1] == "d00_te.dat rows 160-959 (fault-free)"


def test_check_disjoint_names_the_overlap():
    class Overlapping(TennesseeEastman):
        def segments(self, split):
            return {"calibration": [Segment("d00.dat", 0, 200)], "training": [Segment("d01.dat", 0, 160)],
                    "test": [Segment("d00.dat", 150, 300)]}[split]

    with pytest.raises(ConfigError, match="d00.dat rows 150-199 are in both calibration and test"):
        Overlapping()


def test_bad_input_is_one_line(tmp_path):
    with pytest.raises(ConfigError, match=re.escape("data.variables: 'XMEAS(42)' is not a variable")):
        TennesseeEastman(variables=["XMEAS(1)", "XMEAS(42)"])
    with pytest.raises(ConfigError, match="data.faults: 22 is not a TE fault"):
        TennesseeEastman(faults=[1, 22])
    with pytest.raises(ConfigError, match="is not a directory"):
        TennesseeEastman(directory=str(tmp_path / "nowhere"))
    te = TennesseeEastman(directory=str(tmp_path))
    with pytest.raises(ConfigError, match="d00.dat is missing in"):
        te.trace("calibration")


def test_without_bibmon_the_preset_names_the_install_and_exits_2(tmp_path):
    # a plain module named bibmon shadows the package: find_spec finds no package, as without the extra
    (tmp_path / "bibmon.py").write_text("raise ImportError('not the package')\n")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}:{ROOT}", "MOSD_OUTPUTS": str(tmp_path / "out")}
    out = subprocess.run([sys.executable, "-m", "mosd", "+experiment=tep", "tracking=none"], capture_output=True,
                         text=True, env=env, cwd=tmp_path, timeout=300)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and 'pip install ".[te]"' in lines[0], out.stderr
    assert out.stdout == ""


def test_mosd_does_not_import_bibmon():
    code = textwrap.dedent("""
        import sys
        from mosd.data.tep import TennesseeEastman
        te = TennesseeEastman()
        te.trace("test")
        print(sorted(m for m in sys.modules if m.split('.')[0] in ('bibmon', 'optuna', 'seaborn', 'statsmodels')))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"

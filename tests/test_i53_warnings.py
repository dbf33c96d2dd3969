"""Issue 53 item 9: FastICA's convergence warning is shown once, on one line, with what it means.

Before: ``python -m mosd +experiment=tep detector=ica debug=tiny tracking=none`` printed the two-line warning
(the message, then the source line that raised it) once per fit: 5 times, 10 lines, from the preflight dry run,
the tuning and the test. The app's warning display (:func:`mosd.app.settings.install_warning_display`) shows
each warning once per process; mosd's own on one line. A ``catch_warnings(record=True)`` (mosd.systems.skab_study
counts FastICA's warnings so) still records every one.
"""
from __future__ import annotations

import io
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

import mosd
from mosd.app.settings import install_warning_display

from test_app import PACKAGE_PARENT

ICA = ("detector=ica: FastICA did not converge in detector.max_iter=1000 iterations (detector.tol=0.0001); "
       "the statistics use its last unmixing matrix")
LATENT = str(Path(mosd.__file__).resolve().parent / "detectors" / "latent.py")


def _warn(text: str, filename: str, category=UserWarning) -> None:
    warnings.warn_explicit(text, category, filename, 319)


def test_a_warning_is_shown_once_and_mosds_own_on_one_line_with_its_meaning(monkeypatch):
    stream = io.StringIO()
    monkeypatch.setattr(sys, "stderr", stream)
    with warnings.catch_warnings():  # restores Python's display afterwards
        warnings.simplefilter("always")
        # the display the process had (Python's, which writes two lines): stands in for it here
        warnings.showwarning = lambda message, category, *args, **kwargs: stream.write(f"LIB {message}\n")
        install_warning_display()
        install_warning_display()  # twice: still one display
        for _ in range(5):  # the dry run, the tuning's fits, the test
            _warn(ICA, LATENT)
        _warn("another of mosd's warnings", LATENT)
        _warn("a library's warning", "/elsewhere/lib.py", RuntimeWarning)
        _warn("a library's warning", "/elsewhere/lib.py", RuntimeWarning)
        _warn("http://alice:s3cret@host:5000 refused", "/elsewhere/lib.py")
    lines = stream.getvalue().splitlines()
    ica = [ln for ln in lines if "FastICA" in ln]
    assert len(ica) == 1 and ica[0].startswith(f"mosd: warning: {ICA} (it means ")
    assert "detector.max_iter or detector.tol" in ica[0] and ica[0].endswith("; shown once)")
    assert "mosd: warning: another of mosd's warnings" in lines
    assert lines.count("LIB a library's warning") == 1  # the display the process had, once
    assert "s3cret" not in stream.getvalue() and "alice:***@host" in stream.getvalue()


def test_recording_warnings_still_sees_every_one():
    with warnings.catch_warnings():
        install_warning_display()
        with warnings.catch_warnings(record=True) as caught:  # as mosd.systems.skab_study counts them
            warnings.simplefilter("always")
            for _ in range(3):
                _warn(ICA, LATENT)
    assert len(caught) == 3 and all(str(w.message) == ICA for w in caught)


@pytest.mark.slow
def test_ica_on_te_prints_its_convergence_warning_once(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env.update(PYTHONPATH=PACKAGE_PARENT, MOSD_OUTPUTS=str(tmp_path / "outputs"))
    done = subprocess.run([sys.executable, "-m", "mosd", "+experiment=tep", "detector=ica", "debug=tiny",
                           "tracking=none"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "FastICA did not converge" in lines[0] and "it means" in lines[0], done.stderr[-3000:]

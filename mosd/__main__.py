"""``python -m mosd`` — the experiment app (see :mod:`mosd.app`); ``python -m mosd report`` — the report."""
import atexit
import os
import sys

#: the exit code a fast exit asked for (:func:`mosd.app.compat.fast_exit`); None: an ordinary exit
MOSD_FAST_EXIT: dict = {"code": None}


def _end_after_the_exit_handlers() -> None:
    """The last exit handler (registered before any other: ``atexit`` runs them last in, first out): after every
    other handler has run (joblib's temporary folders, logging's flush, a sweep's parent run), a fast exit ends
    the process here, skipping the interpreter's teardown (0.4-0.7 s of destructors with Hydra, numba, SciPy and
    matplotlib loaded)."""
    code = MOSD_FAST_EXIT["code"]
    if code is None:
        return
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can reach it
            pass
    os._exit(code)


atexit.register(_end_after_the_exit_handlers)  # before mosd.app's imports register theirs

from .app import main  # noqa: E402  (after the registration above)

if __name__ == "__main__":
    sys.exit(main())

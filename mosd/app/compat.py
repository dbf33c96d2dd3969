"""The app's only contact with other libraries' private parts: each is reached here and nowhere else.

``tests/test_compat.py`` checks every adapter against the installed versions, so
that an upgrade that moves or changes one fails there, naming what changed,
rather than somewhere in a run. (The optimiser's worker pool has its own
adapter, :mod:`mosd.optim.workers`: the science core cannot import the app.)

* :func:`hydra_args_parser` — Hydra's command-line parser
  (``hydra._internal.utils.get_args_parser``). Preflight must read a command line
  exactly as ``hydra.main`` will, and Hydra has no public parser.
* :func:`run_exit_handlers` — ``atexit._run_exitfuncs``: the fast exit
  (:func:`mosd.app.exit_now`) runs the registered cleanup handlers, then skips
  the interpreter's teardown. The standard library has no public way to run them.
* :func:`unverified_tls_context` — ``ssl._create_unverified_context``: preflight's
  look at a tracking server honours MLflow's ``MLFLOW_TRACKING_INSECURE_TLS`` as
  MLflow's client does (no certificate check, no host name check); the standard
  library's public way to build that context is this private factory.
* :data:`MLFLOW_CORE_TABLES`, :data:`MLFLOW_MIGRATION_LEFTOVER`,
  :data:`MLFLOW_VERSION_TABLE` — what :mod:`mosd.app.store` reads of MLflow's sqlite
  schema (with the standard library, read-only: importing MLflow costs seconds,
  and preflight must judge a store before any work).

What used to be private and is no longer used: Hydra's ``BasicSweeper`` (the
jobs of a sweep are expanded with the public override API,
:func:`sweep_jobs`) and Hydra's error text (a composition error is read from
the exception's public attributes, :func:`composition_error`).
"""
from __future__ import annotations

import itertools
from typing import Any, Sequence

#: Tables every MLflow tracking store has (MLflow creates them first, then migrates).
MLFLOW_CORE_TABLES = ("experiments", "runs", "alembic_version")
#: Prefix of the tables an alembic batch migration works on; one left over means a migration was killed.
MLFLOW_MIGRATION_LEFTOVER = "_alembic_tmp_"
#: The table that holds the schema revision (one row once a creation or migration finished).
MLFLOW_VERSION_TABLE = "alembic_version"
#: The table of runs (counted: a damaged store that holds runs is refused, never moved aside).
MLFLOW_RUNS_TABLE = "runs"


def hydra_args_parser():
    """Hydra's own ``argparse`` parser of a ``hydra.main`` command line (private API, see the module)."""
    from hydra._internal.utils import get_args_parser

    return get_args_parser()


def run_exit_handlers() -> None:
    """Run and clear the ``atexit`` handlers now (private API, see the module)."""
    import atexit

    atexit._run_exitfuncs()


def unverified_tls_context():
    """An SSL context that checks neither the certificate nor the host name (private API, see the module)."""
    import ssl

    return ssl._create_unverified_context()


def sweep_jobs(parsed: Sequence[Any]) -> list[list[str]]:
    """The override lists of the jobs Hydra's basic sweeper runs for ``parsed`` (Hydra ``Override`` objects).

    The same expansion as the basic sweeper's: one list of ``key=value`` strings
    per override key (a later override of a key replaces an earlier one), their
    Cartesian product in command-line order. Raises ValueError for a sweep that
    is not a list of values (an interval), which the basic sweeper refuses too.
    """
    choices: dict[str, list[str]] = {}
    for override in parsed:
        key = override.get_key_element()
        if override.is_sweep_override():
            if not override.is_discrete_sweep():
                raise ValueError(f"{override.input_line}: the basic sweeper takes lists and ranges of values, "
                                 f"not a {override.value_type.name.lower()} sweep")
            choices[key] = [f"{key}={value}" for value in override.sweep_string_iterator()]
        else:
            choices[key] = [f"{key}={override.get_value_element_as_str()}"]
    return [list(job) for job in itertools.product(*choices.values())]


def composition_error(exc: BaseException) -> tuple[str, Any] | None:
    """What a Hydra composition error is about, from the exception's public attributes.

    Returns ``("option", (group, name, allowed))`` for an option that does not
    exist, ``("key", full_key)`` for an override of a key that does not exist,
    else None (the caller reports the exception's own text).
    """
    from hydra.errors import ConfigCompositionException, MissingConfigException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError

    if isinstance(exc, MissingConfigException) and exc.missing_cfg_file and exc.options:
        group, _, name = str(exc.missing_cfg_file).rpartition("/")
        return "option", (group, name, list(exc.options))
    cause = exc.__cause__
    if (isinstance(exc, ConfigCompositionException) and isinstance(cause, (ConfigKeyError, ConfigAttributeError))
            and getattr(cause, "full_key", None)):
        return "key", str(cause.full_key)
    return None


class _RedactingStdout:
    """A text stream that writes every complete line of it through :func:`mosd.app.settings.redacted`."""

    def __init__(self, stream):
        self._stream, self._pending = stream, ""

    def write(self, text: str) -> int:
        from .settings import redacted

        self._pending += text
        if "\n" in self._pending:
            lines, self._pending = self._pending.rsplit("\n", 1)
            self._stream.write(redacted(lines) + "\n")
        return len(text)

    def flush(self) -> None:
        from .settings import redacted

        if self._pending:
            self._stream.write(redacted(self._pending))
            self._pending = ""
        self._stream.flush()

    def __getattr__(self, name):  # isatty, encoding, fileno: the real stream's
        return getattr(self._stream, name)


def redacted_stdout():
    """Hydra's ``--cfg``/``--info`` print the composed config on stdout with ``print``, with no hook for a
    filter: a password in ``tracking.uri`` is masked on its way out (a context manager)."""
    import contextlib
    import sys

    @contextlib.contextmanager
    def redacting():
        stream = _RedactingStdout(sys.stdout)
        try:
            with contextlib.redirect_stdout(stream):
                yield
        finally:
            stream.flush()

    return redacting()

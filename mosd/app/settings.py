"""Where runs are tracked: the ``tracking`` config section, validated, and the default store.

The tracking URI is always explicit; the default is a sqlite file under the
outputs root (an absolute path), artifacts next to it. Nothing here imports
MLflow or Hydra (``mosd report`` and preflight read it).
"""
from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping
from urllib.parse import urlparse

from ..validation import ConfigError

#: Store schemes accepted for ``tracking.uri`` (MLflow 3.17 refuses the plain file store).
STORE_SCHEMES = ("sqlite", "postgresql", "mysql", "mssql", "http", "https", "databricks")
#: Environment variable that overrides the default outputs root.
OUTPUTS_ENV = "MOSD_OUTPUTS"
TRACKING_KEYS = ("enabled", "uri", "artifact_root", "experiment")
#: ``scheme://user:password@`` in any text: the password of a database or server URI; also as Hydra
#: writes an override in its files and logs (``postgresql\://user\:password@``, colons escaped).
_CREDENTIALS = re.compile(r"(?P<head>\b[A-Za-z][A-Za-z0-9+.-]*\\?://[^:/@\s\\]*)(?P<colon>\\?:)[^@/\s]+@")


def redacted(text: str) -> str:
    """``text`` with the password of every URI in it masked: ``postgresql://user:***@host/db``.

    For everything mosd prints or records (the console, ``summary.json``, the run
    directory's config files, MLflow params and tags); the run itself connects with
    the real URI. A password holding ``/`` or ``@`` must be percent-encoded in a URI
    anyway (``%2F``, ``%40``), so it never ends the match early.
    """
    return _CREDENTIALS.sub(r"\g<head>\g<colon>***@", text)


def without_password(uri: str) -> str:
    """``uri`` without its (masked) password, for a driver that reads it from its environment.

    A database keeps its user (``postgresql://user@host/db``: ``PGPASSWORD``,
    ``~/.pgpass``); an HTTP server loses the user too (MLflow then sends
    ``MLFLOW_TRACKING_USERNAME``/``MLFLOW_TRACKING_PASSWORD``, which a user in the URI would override).
    """
    def drop(match: re.Match) -> str:
        head = match.group("head")
        scheme = head.partition("://")[0].rstrip("\\")
        return head[:head.index("//") + 2] if scheme.lower() in ("http", "https") else f"{head}@"

    return _CREDENTIALS.sub(drop, uri)


class RedactCredentials(logging.Filter):
    """Masks URI passwords in log records (Hydra's launchers log every job's overrides on the console)."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        masked = redacted(message)
        if masked != message:
            record.msg, record.args = masked, None
        return True


def default_outputs_root() -> Path:
    """The outputs root: ``$MOSD_OUTPUTS`` or ``./outputs``, made absolute."""
    return Path(os.environ.get(OUTPUTS_ENV) or "outputs").expanduser().resolve()


def default_tracking_uri(outputs_root: str | os.PathLike | None = None) -> str:
    """``sqlite:///<abs outputs root>/mlflow.db`` (the store ``mosd`` and ``mosd report`` use)."""
    root = default_outputs_root() if outputs_root is None else Path(outputs_root).expanduser().resolve()
    return f"sqlite:///{root / 'mlflow.db'}"


@dataclass(frozen=True)
class TrackingSettings:
    """Where runs go: tracking URI, artifact root URI and experiment name."""

    uri: str
    artifact_root: str
    experiment: str

    @classmethod
    def from_config(cls, tracking: Mapping[str, Any], outputs_root: str) -> "TrackingSettings | None":
        """Validate the ``tracking`` config section; None when tracking is disabled."""
        unknown = sorted(set(tracking) - set(TRACKING_KEYS))
        if unknown:
            raise ConfigError(f"tracking.{unknown[0]} is not a tracking key; allowed: {', '.join(TRACKING_KEYS)}")
        enabled = tracking.get("enabled", True)
        if not isinstance(enabled, bool):
            raise ConfigError(f"tracking.enabled={enabled!r} is not allowed; allowed: true, false")
        if not enabled:
            return None
        root = Path(str(outputs_root)).expanduser().resolve()
        uri = tracking.get("uri") or default_tracking_uri(root)
        scheme = urlparse(str(uri)).scheme.split("+")[0]
        if scheme not in STORE_SCHEMES:
            raise ConfigError(f"tracking.uri={uri!r} has no supported scheme; allowed: {', '.join(STORE_SCHEMES)} URIs")
        artifact_root = tracking.get("artifact_root") or str(root / "mlartifacts")
        if not urlparse(str(artifact_root)).scheme:
            artifact_root = Path(str(artifact_root)).expanduser().resolve().as_uri()
        experiment = tracking.get("experiment")
        if not isinstance(experiment, str) or not experiment.strip():
            raise ConfigError(f"tracking.experiment={experiment!r} is not allowed; allowed: a non-empty name")
        return cls(uri=str(uri), artifact_root=str(artifact_root), experiment=experiment)



#: What a warning means for the run, said beside it (the warning's first words -> one sentence): a warning that a
#: user cannot judge is noise
WARNING_MEANINGS = {
    "detector=ica: FastICA did not converge": (
        "it means the independent components are FastICA's last iterate, not a converged solution; the run goes "
        "on with it, its limits set on the same statistics, so FAR and MDR are those of that matrix; a larger "
        "detector.max_iter or detector.tol lets FastICA converge"),
}

_PACKAGE = Path(__file__).resolve().parents[1]


def _from_mosd(filename: str) -> bool:
    try:
        return Path(filename).resolve().is_relative_to(_PACKAGE)
    except (OSError, ValueError):
        return False


def install_warning_display() -> None:
    """How this process shows warnings: each once, URI passwords masked, mosd's own on one line with what it means.

    * a warning is shown once per process (its category and text): the same fit repeated by the preflight
      dry run, the tuning and the test (FastICA that does not converge) printed it once per fit, each time
      with the source line that raised it (issue 53 item 9);
    * mosd's own warnings (raised in this package) are one line, ``mosd: warning: TEXT``, followed on the same line
      by what the warning means where :data:`WARNING_MEANINGS` knows it;
    * other libraries' warnings keep Python's display; a URI's password is masked in every warning (Hydra warns
      with a callback's exception text).

    ``warnings.catch_warnings(record=True)`` still records every warning (it replaces the display while it runs):
    mosd.systems.skab_study counts FastICA's that way.
    """
    import sys
    import warnings

    shown = warnings.showwarning
    if getattr(shown, "redacts", False):
        return
    seen: set[tuple[type, str]] = set()

    def show(message, category, filename, lineno, file=None, line=None):
        text = redacted(str(message))
        if (category, text) in seen:
            return
        seen.add((category, text))
        if not _from_mosd(filename):
            shown(text, category, filename, lineno, file, line)
            return
        meaning = next((m for start, m in WARNING_MEANINGS.items() if text.startswith(start)), None)
        stream = file if file is not None else sys.stderr
        try:
            stream.write(f"mosd: warning: {text}" + (f" ({meaning}; shown once)" if meaning else "") + "\n")
        except (OSError, ValueError):  # a closed stream: nothing more can reach it
            pass

    show.redacts = True
    warnings.showwarning = show


#: the name the app called it by before it showed warnings once (mosd.app.main)
redact_warnings = install_warning_display

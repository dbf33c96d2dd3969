"""The package list, found rather than kept by hand: every package under ``mosd/`` and every config group of
``conf/``, shipped as ``mosd.conf`` (``mosd.app.config`` finds it there after a wheel install).

Everything else about the build is in ``pyproject.toml``; a new component package or config group needs no
edit here.
"""
from pathlib import Path

from setuptools import find_packages, setup

ROOT = Path(__file__).resolve().parent
CONF = ROOT / "conf"


def packages() -> list[str]:
    """``mosd`` and its subpackages, ``mosd.conf`` and one ``mosd.conf.<group>`` per directory below ``conf/``
    (nested ones too: ``conf/debug/tiny/`` is ``mosd.conf.debug.tiny``)."""
    groups = sorted(".".join(p.relative_to(CONF).parts) for p in CONF.rglob("*")
                    if p.is_dir() and not any(part.startswith((".", "_")) for part in p.relative_to(CONF).parts))
    return [*find_packages(where=str(ROOT), include=["mosd", "mosd.*"]), "mosd.conf",
            *(f"mosd.conf.{group}" for group in groups)]


if __name__ == "__main__":  # how pip and the build backend run it; tests import packages() alone
    setup(packages=packages(), package_dir={"mosd.conf": "conf"})

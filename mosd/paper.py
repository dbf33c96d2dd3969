"""``python -m mosd.paper ...``: paper 000's tables, kept as a documented command name.

The code is the package :mod:`mosd.systems.paper000` (a system like the others); this module
re-exports its public names so that ``from mosd import paper`` keeps working.
"""
from .systems.paper000 import *  # noqa: F401,F403
from .systems.paper000 import __all__, main  # noqa: F401

if __name__ == "__main__":
    raise SystemExit(main())

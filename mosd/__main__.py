"""``python -m mosd`` — the experiment app (see :mod:`mosd.app`); ``python -m mosd report`` — the report."""
import sys

from .app import main

if __name__ == "__main__":
    sys.exit(main())

"""``python -m mosd.systems.paper000 ...``: the same command as ``python -m mosd.paper ...``."""
from . import main

raise SystemExit(main())

"""``python -m mosd.replay --opcua [--port P] [--speed S] FILE``: a recorded table replayed as a live OPC UA
server (:mod:`mosd.live.replay`; docs/how-to/opcua.md)."""
import sys

from .live.replay import main

if __name__ == "__main__":
    sys.exit(main())

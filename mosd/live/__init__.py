"""A tuned detector on a live plant over OPC UA (issue 52; docs/how-to/opcua.md).

* :mod:`mosd.live.align` — samples aligned to the model's time step, and the training data's gap
  policy applied causally (no asyncua: tested on its own);
* :mod:`mosd.live.replay` — ``python -m mosd.replay --opcua FILE``: an asyncua server on 127.0.0.1
  replaying a recorded table at a chosen speed, with history;
* :mod:`mosd.live.client` — ``mosd monitor --opcua URL``: subscribe, score each aligned sample with the
  pipeline's one-step update and the carried state, write the outputs back, log, checkpoint;
* :mod:`mosd.live.bench` — latency and throughput against the replay server.

asyncua is the optional extra ``opcua``; :func:`require_asyncua` is the one line when it is missing.
"""
from __future__ import annotations

from ..validation import ConfigError

INSTALL = "pip install 'mosd[opcua]'"


def require_asyncua():
    """The asyncua module, or a one-line :class:`ConfigError` naming the extra to install."""
    try:
        import asyncua
    except ImportError:
        raise ConfigError(f"OPC UA needs the optional package asyncua: {INSTALL}") from None
    return asyncua

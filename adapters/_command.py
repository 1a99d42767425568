"""What the adapters' console commands share: logging, and a stop on SIGINT / SIGTERM."""

from __future__ import annotations

import logging
import signal
import threading


def prepare() -> threading.Event:
    """Log to stderr with timestamps; return an event that SIGINT or SIGTERM sets, for the
    command to wait on and then close its adapter cleanly."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop

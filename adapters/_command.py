"""What the adapters' console commands share: how they reach the service, logging, and a stop
on SIGINT / SIGTERM."""

from __future__ import annotations

import argparse
import logging
import signal
import threading

from service.client import TrackingClient

#: the service's endpoint on its embedded default
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def add_service_arguments(ap: argparse.ArgumentParser) -> None:
    """``--connect`` (repeatable) and ``--prefix``: where the service is."""
    ap.add_argument("-e", "--connect", action="append", default=None, metavar="ENDPOINT",
                    help=f"the service's Zenoh endpoint, repeatable (default: {DEFAULT_ENDPOINT})")
    ap.add_argument("--prefix", default="arcf/v1",
                    help="the service's key-expression prefix (default: %(default)s)")


def service_client(args: argparse.Namespace) -> TrackingClient:
    """A client of the service the arguments name."""
    return TrackingClient(connect=args.connect or [DEFAULT_ENDPOINT], prefix=args.prefix)


def prepare() -> threading.Event:
    """Log to stderr with timestamps; return an event that SIGINT or SIGTERM sets, for the
    command to wait on and then close its adapter cleanly."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop

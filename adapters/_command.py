"""What the adapters' console commands share: how they reach the service, logging, and a stop
on SIGINT / SIGTERM."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from collections.abc import Mapping, Sequence
from typing import Any

from arcf.service.client import TrackingClient

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


def add_override_arguments(ap: argparse.ArgumentParser) -> None:
    """``--preset`` and ``--set NAME=VALUE`` (repeatable): what the commands' sessions run."""
    ap.add_argument("--preset", default="arcf-hc")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="preset override for the sessions, repeatable; nested fields by "
                    "their dotted names, e.g. state.reacquire=false")


def _value(text: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_overrides(ap: argparse.ArgumentParser, items: Sequence[str]) -> dict[str, Any]:
    """``--set`` items as overrides (booleans, numbers, else strings); a malformed item is a
    usage error."""
    overrides = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            ap.error(f"--set needs NAME=VALUE, got {item!r}")
        overrides[name] = _value(value)
    return overrides


def check_preset(client: TrackingClient, preset: str, overrides: Mapping[str, Any]) -> None:
    """Refuse, before any station clicks, a preset or an override the service would refuse
    (its ``presets`` reply says what each override accepts). Raises ``ValueError``."""
    info = client.presets()
    if preset not in {p.name for p in info.presets}:
        raise ValueError(f"unknown preset {preset!r}; the service runs "
                         f"{sorted(p.name for p in info.presets)}")
    accepts = {p.name: p for p in info.parameters}
    kinds = {"bool": (bool,), "int": (int,), "float": (int, float), "str": (str,)}
    for name, value in overrides.items():
        p = accepts.get(name)
        if p is None:
            raise ValueError(f"unknown override {name!r}")
        if not isinstance(value, kinds[p.kind]) or (p.kind != "bool" and isinstance(value, bool)):
            raise ValueError(f"override {name}={value!r}: a {p.kind} is needed")
        if p.choices is not None and value not in p.choices:
            raise ValueError(f"override {name}={value!r}: one of {p.choices}")
        if p.kind in ("int", "float") and isinstance(value, int | float) and not (
                (p.minimum is None or value >= p.minimum)
                and (p.maximum is None or value <= p.maximum)):
            raise ValueError(f"override {name}={value!r}: within [{p.minimum}, {p.maximum}]")

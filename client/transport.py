"""Zenoh sessions for the service and its clients (configuration only; no work in callbacks)."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ParamSpec

import zenoh

P = ParamSpec("P")

#: zenoh-python's examples' flags, shared by every command that opens a Zenoh session:
#: ``-m`` mode, ``-e`` connect endpoint, ``-l`` listen endpoint, ``-c`` Zenoh config file.
ZENOH_SHORT_FLAGS = {"mode": "-m", "connect": "-e", "listen": "-l", "zenoh_config": "-c"}

#: every arcf process logs lines in this form (the service, its workers, the adapters)
LOG_FORMAT = "%(asctime)s %(name)s %(message)s"


def add_zenoh_arguments(parser: Any, *, listen_default: str = "") -> None:
    """The Zenoh flags of a command that is not ``arcf-service`` (whose flags come from its
    settings, with the same short names): ``-e/--connect``, ``-l/--listen``,
    ``-c/--zenoh-config``."""
    parser.add_argument(ZENOH_SHORT_FLAGS["connect"], "--connect", action="append",
                        metavar="ENDPOINT", help="Zenoh endpoint to connect to (repeatable)")
    parser.add_argument(ZENOH_SHORT_FLAGS["listen"], "--listen", action="append",
                        metavar="ENDPOINT", help="Zenoh endpoint to listen on (repeatable)"
                        + (f"; default {listen_default}" if listen_default else ""))
    parser.add_argument(ZENOH_SHORT_FLAGS["zenoh_config"], "--zenoh-config", type=Path,
                        metavar="FILE", help="Zenoh JSON5 config file")


def make_config(
    mode: str,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: Path | None = None,
    lease_ms: int | None = None,
    max_message_size: int | None = None,
    open_timeout_ms: int | None = None,
    timestamping: bool = False,
) -> zenoh.Config:
    """A Zenoh config: the file (if any), then mode, explicit endpoints and scouting off.

    Endpoints are always explicit (a peer's default listens on every interface) and multicast
    scouting is off, so a service on loopback stays on loopback. ``max_message_size`` bounds
    what this session reassembles from a link (Zenoh's default: 1 GiB per message).
    ``open_timeout_ms``: how long opening a link to one endpoint may take before the next
    of ``connect`` is tried (Zenoh's default, 10 s, is what a client whose router became
    unreachable, not dead, waits on it before moving to the next one).
    ``timestamping``: stamp what this session publishes (Zenoh's HLC), which zenoh-ext's
    advanced publisher needs for its cache (a station's recent video, for the service).
    """
    conf = zenoh.Config.from_file(str(config_file)) if config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if lease_ms:
        conf.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    if max_message_size:
        conf.insert_json5("transport/link/rx/max_message_size", str(int(max_message_size)))
    if open_timeout_ms:
        conf.insert_json5("transport/unicast/open_timeout", str(int(open_timeout_ms)))
    if timestamping:
        conf.insert_json5("timestamping/enabled", "true")
    return conf


def _opening(configure: Callable[P, zenoh.Config]) -> Callable[P, zenoh.Session]:
    def open_session(*args: P.args, **kwargs: P.kwargs) -> zenoh.Session:
        """A Zenoh session opened on :func:`make_config`'s config (same arguments)."""
        return zenoh.open(configure(*args, **kwargs))
    return open_session


#: A Zenoh session on :func:`make_config`'s config: ``open_session("client", connect=[...])``.
open_session = _opening(make_config)

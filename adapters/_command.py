"""What the adapters' console commands share: how they reach the service, logging, a stop
on SIGINT / SIGTERM, and their counts on a Prometheus endpoint."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from arcf.client import ServiceError, TrackingClient
from arcf.client.transport import LOG_FORMAT

#: the service's endpoint on its embedded default
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def add_service_arguments(ap: argparse.ArgumentParser) -> None:
    """``--connect`` (repeatable), ``--prefix`` and ``--wait-s``: where the service is, and
    how long to wait for it."""
    ap.add_argument("-e", "--connect", action="append", default=None, metavar="ENDPOINT",
                    help=f"the service's Zenoh endpoint, repeatable (default: {DEFAULT_ENDPOINT})")
    ap.add_argument("--prefix", default="arcf/v1",
                    help="the service's key-expression prefix (default: %(default)s)")
    ap.add_argument("--wait-s", type=float, default=120.0, metavar="SECONDS",
                    help="how long to wait for the service to answer at start (it may start "
                    "after this command; default %(default)s, 0: ask once)")


def service_client(args: argparse.Namespace, **kwargs: Any) -> TrackingClient:
    """A client of the service the arguments name (it may not answer yet)."""
    return TrackingClient(connect=args.connect or [DEFAULT_ENDPOINT], prefix=args.prefix,
                          **kwargs)


def add_metrics_argument(ap: argparse.ArgumentParser) -> None:
    """``--metrics-port``: where the adapter's counts are served for Prometheus."""
    ap.add_argument("--metrics-port", type=int, default=-1, metavar="PORT",
                    help="serve the adapter's counts (what it refused, dropped or carried out) "
                    "as arcf_adapter_events_total{adapter,event} on http://127.0.0.1:PORT/"
                    "metrics (0: any free port; default: off)")


class CountsCollector:
    """A Prometheus collector over an adapter's ``counts`` (read at each scrape, so the
    adapter keeps counting as it does): ``arcf_adapter_events_total{adapter, event}``."""

    def __init__(self, adapter: str, counts: Callable[[], Mapping[str, int]]) -> None:
        self.adapter, self.counts = adapter, counts

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily

        family = CounterMetricFamily(
            "arcf_adapter_events", "What the adapter refused, dropped or carried out, by event "
            "(its counts: unsigned, refused, bad_track, ...)", labels=["adapter", "event"])
        for event, n in sorted(dict(self.counts()).items()):
            family.add_metric([self.adapter, event], float(n))
        yield family


def serve_counts(adapter: str, counts: Callable[[], Mapping[str, int]], port: int,
                 host: str = "127.0.0.1") -> tuple[Any, str]:
    """Serve ``counts`` on ``http://host:port/metrics``; (the server, its URL)."""
    from prometheus_client import CollectorRegistry, start_http_server

    registry = CollectorRegistry()
    registry.register(CountsCollector(adapter, counts))
    server, _ = start_http_server(port, addr=host, registry=registry)
    return server, f"http://{host}:{server.server_port}/metrics"


#: the first wait between two attempts to reach the service, and the longest
RETRY_S, RETRY_MAX_S = 0.5, 5.0


def wait_for_service(args: argparse.Namespace, logger: logging.Logger, stop: threading.Event,
                     **kwargs: Any) -> TrackingClient | None:
    """A client of the service, once the service answers a ``status`` request.

    The adapters may start before the service (or its router): each attempt that fails
    (no Zenoh router at the endpoint, or no service answering behind it) is logged with the
    reason and tried again, after 0.5 s, then twice as long each time up to 5 s, for
    ``--wait-s`` seconds in all. Returns None (the reason logged) when that time passes or
    ``stop`` is set first: the command then exits with status 2 rather than a traceback."""
    import zenoh  # the adapters' transport; imported here to keep this module light

    endpoints = ", ".join(args.connect or [DEFAULT_ENDPOINT])
    deadline = time.monotonic() + max(0.0, args.wait_s)
    attempt = 0
    while True:
        attempt += 1
        client: TrackingClient | None = None
        try:
            client = service_client(args, **kwargs)
            client.status(timeout=2.0)
            if attempt > 1:
                logger.info("the tracking service answers at %s", endpoints)
            return client
        except (zenoh.ZError, TimeoutError) as exc:
            why = (f"no Zenoh router at {endpoints}" if isinstance(exc, zenoh.ZError)
                   else f"nothing answers on {args.prefix}/control at {endpoints}")
            if client is not None:
                client.close()
        left = deadline - time.monotonic()
        if left <= 0:
            logger.error("the tracking service did not answer (%s) in %.0f s: giving up",
                         why, args.wait_s)
            return None
        wait = min(RETRY_S * 2 ** (attempt - 1), RETRY_MAX_S, left)
        logger.warning("waiting for the tracking service: %s (attempt %d; next in %.1f s, "
                       "%.0f s left)", why, attempt, wait, left)
        if stop.wait(wait):
            return None


def prepare() -> threading.Event:
    """Log to stderr with timestamps; return an event that SIGINT or SIGTERM sets, for the
    command to wait on and then close its adapter cleanly."""
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def connect(args: argparse.Namespace, logger: logging.Logger, **kwargs: Any
            ) -> tuple[TrackingClient | None, threading.Event]:
    """A command's start: logging and its stop event (:func:`prepare`), then a client once
    the service answers (:func:`wait_for_service`; None: exit with status 2)."""
    stop = prepare()
    return wait_for_service(args, logger, stop, **kwargs), stop


def add_session_arguments(ap: argparse.ArgumentParser) -> None:
    """What a command that starts sessions takes: ``--preset`` and ``--set NAME=VALUE``
    (repeatable; ``args.set`` is then the overrides, a dict), and ``--metrics-port``."""
    ap.add_argument("--preset", default="arcf-hc")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    type=_override,
                    help="preset override for the sessions, repeatable; nested fields by "
                    "their dotted names, e.g. state.reacquire=false")
    add_metrics_argument(ap)


def _override(item: str) -> tuple[str, Any]:
    """One ``--set NAME=VALUE``: booleans, numbers, else a string (argparse reports a
    malformed item as a usage error)."""
    name, sep, text = item.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"--set needs NAME=VALUE, got {item!r}")
    return name, _value(text)


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


def check_preset(client: TrackingClient, preset: str, overrides: Mapping[str, Any]) -> None:
    """Refuse, before any station clicks, a preset or an override the service would refuse:
    the service checks them as it checks a start (``TrackingClient.check``). Raises
    ``ValueError`` with the service's reason."""
    try:
        client.check(preset, dict(overrides))
    except ServiceError as exc:
        raise ValueError(exc.error.message) from exc

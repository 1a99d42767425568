"""``arcf-router``: a plain Zenoh router, for running several service instances on one machine
without Docker or ``zenohd``, and for a fleet's router mesh.

    arcf-router --listen tcp/127.0.0.1:7447
    arcf-service --mode client --connect tcp/127.0.0.1:7447 --instance-id a --metrics-port 9464
    arcf-service --mode client --connect tcp/127.0.0.1:7447 --instance-id b --metrics-port 9465

    # one router per host, each connected to the others: a mesh (docs/deploy-a-fleet.md)
    arcf-router --listen tcp/0.0.0.0:7447 --connect tcp/host-b:7447 --metrics-port 9465

It is Zenoh's own router (the one ``zenohd`` runs), opened through the Python binding; nothing of
ours is in the data path. With ``--metrics-port`` it serves Prometheus metrics read from its
own session's admin space at each scrape: the Zenoh sessions linked to it by kind (stations
and service instances are clients, the mesh's other routers routers) and their links. In
production use the official ``eclipse/zenoh`` image (``deploy/compose.yaml``).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
from collections import Counter
from collections.abc import Iterator
from typing import Any

from arcf.client.transport import LOG_FORMAT, add_zenoh_arguments, open_session

log = logging.getLogger(__name__)

#: the kinds of Zenoh session a router links to
KINDS = ("client", "peer", "router")


def transports(session: Any, timeout: float = 1.0) -> tuple[Counter[str], int]:
    """The Zenoh sessions linked to ``session`` (a router's), counted by kind, and their links,
    from its own admin space (``@/<zid>/session/transport/unicast/...``)."""
    kinds: Counter[str] = Counter()
    links = 0
    prefix = f"@/{session.info.zid()}/session/transport/unicast/"
    for reply in session.get(prefix + "**", timeout=timeout):
        if reply.ok is None:
            continue
        rest = str(reply.ok.key_expr)[len(prefix):].split("/")
        if len(rest) == 1:
            try:
                kinds[str(json.loads(reply.ok.payload.to_bytes())["whatami"])] += 1
            except (ValueError, KeyError, TypeError):
                log.debug("unreadable admin entry %s", reply.ok.key_expr)
        elif len(rest) == 3 and rest[1] == "link":
            links += 1
    return kinds, links


class RouterCollector:
    """Prometheus collector of a router session's links, read at each scrape."""

    def __init__(self, session: Any, version: str) -> None:
        self.session = session
        self.version = version

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import GaugeMetricFamily, InfoMetricFamily

        kinds, links = transports(self.session)
        info = InfoMetricFamily("arcf_router", "This Zenoh router: its id and Zenoh's version")
        info.add_metric([], {"zid": str(self.session.info.zid()), "zenoh": self.version})
        yield info
        sessions = GaugeMetricFamily(
            "arcf_router_sessions", "Zenoh sessions linked to this router, by kind (stations "
            "and service instances: client; the mesh's other routers: router)",
            labels=["whatami"])
        for kind in sorted(set(KINDS) | set(kinds)):
            sessions.add_metric([kind], kinds.get(kind, 0))
        yield sessions
        yield GaugeMetricFamily("arcf_router_links", "Links (connections) of those sessions",
                                value=links)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="arcf-router", description=__doc__.splitlines()[0])
    add_zenoh_arguments(ap, listen_default="tcp/127.0.0.1:7447")
    ap.add_argument("--metrics-port", type=int, default=-1,
                    help="serve Prometheus metrics on this port (0: any free one; default: "
                         "none)")
    ap.add_argument("--metrics-host", default="127.0.0.1",
                    help="the metrics' address (default 127.0.0.1)")
    ap.add_argument("--lease-ms", type=int, default=None,
                    help="the Zenoh lease: a link silent this long is closed (default: the "
                         "config file's, else Zenoh's 10 s); what a hung or cut-off router "
                         "or client costs before the others move on")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    listen = args.listen or ["tcp/127.0.0.1:7447"]
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    with open_session("router", listen=listen, connect=args.connect or (),
                      config_file=args.zenoh_config, lease_ms=args.lease_ms) as session:
        metrics = ""
        if args.metrics_port >= 0:
            from importlib.metadata import version

            from prometheus_client import CollectorRegistry, start_http_server

            registry = CollectorRegistry()
            registry.register(RouterCollector(session, version("eclipse-zenoh")))
            http, _ = start_http_server(args.metrics_port, addr=args.metrics_host,
                                        registry=registry)
            metrics = f"; metrics http://{args.metrics_host}:{http.server_port}/metrics"
        print(f"arcf-router ready: {', '.join(listen)}{metrics}", flush=True)
        stop.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())

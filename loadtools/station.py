"""A ground station as a program of its own, for runs where it lives in another network
namespace than the test that reads what it saw (:mod:`arcf.loadtools.netfleet`).

    python -m arcf.loadtools.station --connect tcp/10.213.20.1:7447 --connect ... \\
        --streams cam-1,cam-2 --fps 5 --frames 600 --out station.json

It streams a real sequence (``failover_fleet``: one session per stream, frames at the same
instants) until SIGTERM, then writes what it sent and received, and the routers it was linked
to over time, as JSON; times are ``time.monotonic()``, which every process of the machine
shares, namespaces or not.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any


def _follow_routers(session: Any, stop: threading.Event, into: list[Any]) -> None:
    """(time, router ids) whenever the station's routers change, polled every 10 ms."""
    last: list[str] | None = None
    while not stop.wait(0.01):
        now = sorted(str(z) for z in session.info.routers_zid())
        if now != last:
            into.append([time.monotonic(), now])
            last = now


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", action="append", required=True, metavar="ENDPOINT")
    ap.add_argument("--streams", required=True, help="comma-separated stream ids")
    ap.add_argument("--sequence", default="truck4_1", help="a UAV123@10fps sequence")
    ap.add_argument("--preset", default="bacf")
    ap.add_argument("--fps", type=float, default=5.0)
    ap.add_argument("--frames", type=int, default=600, help="per stream (a bound)")
    ap.add_argument("--lease-ms", type=int, default=3000,
                    help="the Zenoh lease: a router that stops answering is left after it")
    ap.add_argument("--open-timeout-ms", type=int, default=1000,
                    help="how long a router that does not answer is tried before the next "
                         "endpoint")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)

    from arcf.client import TrackingClient
    from arcf.client.transport import open_session
    from arcf.eval import load_dataset

    from .driver import Clip, failover_fleet

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    clip = Clip.of(load_dataset("uav123_10fps", sequences=[args.sequence])[0])
    session = open_session("client", connect=args.connect, lease_ms=args.lease_ms,
                           open_timeout_ms=args.open_timeout_ms)
    routers: list[Any] = []
    follower = threading.Thread(target=_follow_routers, args=(session, stop, routers),
                                daemon=True)
    follower.start()
    client = TrackingClient(session=session)
    fleet = failover_fleet(client, clip, args.streams.split(","), preset=args.preset,
                           fps=args.fps, frames=args.frames)
    print("station ready", flush=True)
    stop.wait()
    fleet.pause()
    seen: dict[str, Any] = {}
    for name in args.streams.split(","):
        record = fleet.ledger[name]
        with record.cond:
            seen[name] = {
                "sent": [[seq, t] for seq, t in record.sent],
                "received": [[r.t, r.frame_seq, r.session_id, r.status, r.dropped,
                              r.latency_s] for r in record.received]}
    args.out.write_text(json.dumps({"routers": routers, "streams": seen}))
    client.close()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``arcf-router``: a plain Zenoh router, for running several service instances on one machine
without Docker or ``zenohd``.

    arcf-router --listen tcp/127.0.0.1:7447
    arcf-service --mode client --connect tcp/127.0.0.1:7447 --instance-id a --metrics-port 9464
    arcf-service --mode client --connect tcp/127.0.0.1:7447 --instance-id b --metrics-port 9465

It is Zenoh's own router (the one ``zenohd`` runs), opened through the Python binding; nothing of
ours is in the data path. In production use the official ``eclipse/zenoh`` image
(``deploy/compose.yaml``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from arcf.client.transport import add_zenoh_arguments, open_session


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="arcf-router", description=__doc__.splitlines()[0])
    add_zenoh_arguments(ap, listen_default="tcp/127.0.0.1:7447")
    args = ap.parse_args(argv)
    listen = args.listen or ["tcp/127.0.0.1:7447"]
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    with open_session("router", listen=listen, connect=args.connect or (),
                      config_file=args.zenoh_config):
        print(f"arcf-router ready: {', '.join(listen)}", flush=True)
        stop.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())

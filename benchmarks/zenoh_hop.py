"""What one Zenoh hop through a router costs, without the service: the floor under the service
profile's "main process" and "worker, the rest" rows.

A bare router, one subscriber and one publisher, each its own process on loopback, all with
``arcf.service.transport.make_config`` (the service's own settings: client mode, scouting off).
The publisher puts messages of the sizes a service carries (a 1280x720 JPEG frame, a result) at
a frame rate; the router's and the subscriber's CPU (``/proc``) is divided by the messages
received. Each link kind (TCP, a Unix socket) runs with Zenoh's shared memory on (its default:
the publisher's large messages go through /dev/shm, on-host only) and off (what a frame from
another host, or a container without a shared /dev/shm, costs).

    python benchmarks/zenoh_hop.py                         # about 2 minutes
    python benchmarks/zenoh_hop.py --sizes 100000 --messages 3000 --rate 300
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

from arcf.loadtools.procs import free_port
from arcf.loadtools.system import cpu_model, cpu_seconds

#: One role per process: "router", "sub" (counts, answers the count on a line of stdin) or
#: "pub" (puts ``count`` messages of ``size`` bytes at ``rate`` a second, then exits).
CHILD = """
import os, sys, time
from arcf.service.transport import make_config
import zenoh
role, endpoint, shm = sys.argv[1], sys.argv[2], sys.argv[3]
conf = make_config("router" if role == "router" else "client",
                   listen=[endpoint] if role == "router" else (),
                   connect=[endpoint] if role != "router" else ())
conf.insert_json5("transport/shared_memory/enabled", shm)
session = zenoh.open(conf)
if role == "router":
    print("ready", flush=True)
    sys.stdin.readline()
elif role == "sub":
    got = [0]
    def count(sample):
        got[0] += 1
    sub = session.declare_subscriber("bench/hop", count)
    print("ready", flush=True)
    sys.stdin.readline()
    print(got[0], flush=True)
    sys.stdin.readline()
else:
    count, size, rate = int(sys.argv[4]), int(sys.argv[5]), float(sys.argv[6])
    pub = session.declare_publisher("bench/hop")
    payload = os.urandom(size)
    time.sleep(1.0)  # the router learns the subscriber's interest
    t0 = time.perf_counter()
    for i in range(count):
        pub.put(payload)
        wait = t0 + (i + 1) / rate - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
    time.sleep(0.5)
"""


def _start(*args: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, "-c", CHILD, *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    if line != "ready":
        proc.kill()
        raise RuntimeError(f"{args[0]} did not start (said {line!r})")
    return proc


def _ask(proc: subprocess.Popen[str]) -> str:
    assert proc.stdin is not None and proc.stdout is not None
    proc.stdin.write("\n")
    proc.stdin.flush()
    return proc.stdout.readline().strip()


def hop(endpoint: str, shm: bool, size: int, count: int, rate: float) -> tuple[float, float, int]:
    """(router CPU ms, subscriber CPU ms) per message received, and the messages received."""
    flag = "true" if shm else "false"
    router = _start("router", endpoint, flag)
    sub = None
    try:
        sub = _start("sub", endpoint, flag)
        time.sleep(0.5)
        r0, s0 = cpu_seconds(router.pid), cpu_seconds(sub.pid)
        subprocess.run([sys.executable, "-c", CHILD, "pub", endpoint, flag, str(count),
                        str(size), str(rate)], check=True, timeout=60 + 2 * count / rate)
        r1, s1 = cpu_seconds(router.pid), cpu_seconds(sub.pid)
        got = int(_ask(sub))
    finally:
        for proc in (sub, router):
            if proc is not None:
                proc.kill()
                proc.wait(timeout=10)
    n = max(got, 1)
    return (r1 - r0) / n * 1e3, (s1 - s0) / n * 1e3, got


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100000,350",
                    help="message bytes, comma-separated (a 720p JPEG frame, a result)")
    ap.add_argument("--messages", type=int, default=1500, help="messages per run")
    ap.add_argument("--rate", type=float, default=150.0, help="messages a second")
    args = ap.parse_args()
    print(f"`python benchmarks/zenoh_hop.py --sizes {args.sizes} --messages {args.messages} "
          f"--rate {args.rate:g}`")
    print(f"{datetime.now(UTC):%Y-%m-%d}, {cpu_model()}, nproc {os.cpu_count()}; "
          f"CPU ms per message received\n")
    print("| link | shared memory | message bytes | router | subscriber | received |")
    print("| --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for link in ("tcp", "unixsock-stream"):
            for shm in (True, False):
                for size in (int(s) for s in args.sizes.split(",") if s):
                    endpoint = (f"tcp/127.0.0.1:{free_port()}" if link == "tcp"
                                else f"unixsock-stream/{Path(tmp) / f'hop-{size}-{shm}.sock'}")
                    router_ms, sub_ms, got = hop(endpoint, shm, size, args.messages, args.rate)
                    print(f"| {link} | {'on' if shm else 'off'} | {size} | {router_ms:.3f} | "
                          f"{sub_ms:.3f} | {got} / {args.messages} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

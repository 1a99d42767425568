"""What one Zenoh hop costs, without the service: the floor under the service profile's "main
process" and "worker, the rest" rows, and what a direct link would save.

Two topologies, each process on loopback with ``arcf.client.transport.make_config`` (the
service's own settings: explicit endpoints, multicast scouting off):

* **router** (what the service does): a bare router, one subscriber and one publisher, both
  clients of the router;
* **direct** (what a station talking straight to a worker would do): the subscriber is a peer
  listening on the endpoint and the publisher a peer connected to it, no router.

The publisher puts messages of the sizes a service carries (a 1280x720 JPEG frame, a result) at
a frame rate; the router's and the subscriber's CPU (``/proc``), and the publisher's own during
its puts, are divided by the messages received. Each link kind (TCP, a Unix socket) runs with
Zenoh's shared memory on (its default: the publisher's large messages go through /dev/shm,
on-host only) and off (what a frame from another host, or a container without a shared
/dev/shm, costs).

    python benchmarks/zenoh_hop.py                         # about 4 minutes
    python benchmarks/zenoh_hop.py --sizes 100000 --messages 3000 --rate 300 --topologies direct
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

from arcf.eval.environment import describe
from arcf.loadtools.procs import free_port
from arcf.loadtools.system import cpu_seconds

#: One role per process: "router", "sub" (counts, answers the count on a line of stdin) or
#: "pub" (puts ``count`` messages of ``size`` bytes at ``rate`` a second, prints its process's
#: CPU seconds over the puts, then exits); the mode and whether it listens on the endpoint or
#: connects to it are the topology's.
CHILD = """
import os, sys, time
from arcf.client.transport import make_config
import zenoh
role, mode, side, endpoint, shm = sys.argv[1:6]
conf = make_config(mode, listen=[endpoint] if side == "listen" else (),
                   connect=[endpoint] if side == "connect" else ())
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
    count, size, rate = int(sys.argv[6]), int(sys.argv[7]), float(sys.argv[8])
    pub = session.declare_publisher("bench/hop")
    payload = os.urandom(size)
    time.sleep(1.0)  # the router (or the peer) learns the subscriber's interest
    c0, t0 = time.process_time(), time.perf_counter()
    for i in range(count):
        pub.put(payload)
        wait = t0 + (i + 1) / rate - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
    time.sleep(0.5)
    print(time.process_time() - c0, flush=True)
"""

#: (mode, side) of the router, the subscriber and the publisher in each topology
TOPOLOGIES = {
    "router": {"router": ("router", "listen"), "sub": ("client", "connect"),
               "pub": ("client", "connect")},
    "direct": {"sub": ("peer", "listen"), "pub": ("peer", "connect")},
}


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


def hop(topology: str, endpoint: str, shm: bool, size: int, count: int,
        rate: float) -> tuple[float | None, float, float, int]:
    """(router, subscriber, publisher) CPU ms per message received (router None without
    one), and the messages received."""
    flag = "true" if shm else "false"
    roles = TOPOLOGIES[topology]

    def args(role: str) -> list[str]:
        return [role, *roles[role], endpoint, flag]

    router = _start(*args("router")) if "router" in roles else None
    sub = None
    try:
        sub = _start(*args("sub"))
        time.sleep(0.5)
        r0 = cpu_seconds(router.pid) if router else 0.0
        s0 = cpu_seconds(sub.pid)
        pub = subprocess.run([sys.executable, "-c", CHILD, *args("pub"), str(count), str(size),
                              str(rate)], check=True, timeout=60 + 2 * count / rate,
                             stdout=subprocess.PIPE, text=True)
        r1 = cpu_seconds(router.pid) if router else 0.0
        s1 = cpu_seconds(sub.pid)
        got = int(_ask(sub))
    finally:
        for proc in (sub, router):
            if proc is not None:
                proc.kill()
                proc.wait(timeout=10)
    n = max(got, 1)
    pub_s = float(pub.stdout.split()[-1])
    return ((r1 - r0) / n * 1e3 if router else None, (s1 - s0) / n * 1e3, pub_s / n * 1e3, got)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100000,350",
                    help="message bytes, comma-separated (a 720p JPEG frame, a result)")
    ap.add_argument("--messages", type=int, default=1500, help="messages per run")
    ap.add_argument("--rate", type=float, default=150.0, help="messages a second")
    ap.add_argument("--topologies", default="router,direct",
                    help=f"comma-separated, of {', '.join(TOPOLOGIES)}")
    args = ap.parse_args()
    topologies = [t for t in args.topologies.split(",") if t]
    if unknown := set(topologies) - set(TOPOLOGIES):
        ap.error(f"unknown topologies: {', '.join(sorted(unknown))}")
    print(f"`python benchmarks/zenoh_hop.py --sizes {args.sizes} --messages {args.messages} "
          f"--rate {args.rate:g} --topologies {args.topologies}`")
    print(f"{datetime.now(UTC):%Y-%m-%d}, {describe()}, Zenoh "
          f"{metadata.version('eclipse-zenoh')}; CPU ms per message received\n")
    print("| topology | link | shared memory | message bytes | router | subscriber | publisher "
          "| received |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for topology in topologies:
            for link in ("tcp", "unixsock-stream"):
                for shm in (True, False):
                    for size in (int(s) for s in args.sizes.split(",") if s):
                        name = f"hop-{topology}-{size}-{shm}.sock"
                        endpoint = (f"tcp/127.0.0.1:{free_port()}" if link == "tcp"
                                    else f"unixsock-stream/{Path(tmp) / name}")
                        router_ms, sub_ms, pub_ms, got = hop(topology, endpoint, shm, size,
                                                             args.messages, args.rate)
                        router = "–" if router_ms is None else f"{router_ms:.3f}"
                        print(f"| {topology} | {link} | {'on' if shm else 'off'} | {size} | "
                              f"{router} | {sub_ms:.3f} | {pub_ms:.3f} | "
                              f"{got} / {args.messages} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

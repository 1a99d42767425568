"""What each instance of a fleet receives to be able to take sessions over, by fleet size.

A Zenoh router and 1, 2 or 3 service instances (client mode, one worker each, on loopback),
and the same total load on the fleet: ``--streams`` streams of a real sequence at ``--fps``,
one session each. Per instance, the bytes a second its main process receives (the TCP bytes
of its own connections, ``ss -ti``), its messages' worth of control, membership, registry
and the workers' last boxes (``last_boxes``): not the frames and results its workers carry.
It should not grow with the sessions' frame rate, nor much with the fleet's size.

    python benchmarks/fanin.py                       # about 2 minutes
    python benchmarks/fanin.py --streams 12 --fps 30 --instances 1,3
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

from _common import parser  # beside this script

ROOT = Path(__file__).resolve().parent.parent


def received_bytes(pid: int) -> int:
    """TCP bytes received so far on the connections process ``pid`` holds (``ss -tinp``)."""
    out = subprocess.run(["ss", "-tinpH"], capture_output=True, text=True, check=True).stdout
    total, mine = 0, False
    for line in out.splitlines():
        if not line.startswith((" ", "\t")):  # a connection's line; its details follow
            mine = f"pid={pid}," in line
        elif mine and (m := re.search(r"bytes_received:(\d+)", line)):
            total += int(m[1])
    return total


def run(instances: int, streams: int, fps: float, seconds: float, preset: str) -> list[float]:
    """Bytes a second each instance's main process received while the fleet tracked."""
    from arcf.client import TrackingClient
    from arcf.eval import load_dataset
    from arcf.loadtools.driver import Clip, failover_fleet
    from arcf.loadtools.procs import RouterProcess, start_instances
    from arcf.loadtools.waiting import wait_until

    clip = Clip.of(load_dataset("uav123_10fps", sequences=["truck4_1"])[0])
    ids = [f"fan-{k}" for k in range(instances)]
    names = [f"cam-{k}" for k in range(streams)]
    with RouterProcess() as router:
        procs = start_instances(ids, router.endpoint)
        try:
            with TrackingClient(connect=[router.endpoint]) as client:
                fleet = failover_fleet(client, clip, names, preset=preset, fps=fps,
                                       frames=int(fps * (seconds + 30)))
                try:
                    wait_until(lambda: all(fleet.ledger[n].received for n in names),
                               timeout=60, what="every stream tracked")
                    time.sleep(2.0)  # the sessions' starts out of the window
                    before = {i: received_bytes(p.pid) for i, p in procs.items()}
                    t0 = time.monotonic()
                    time.sleep(seconds)  # the window measured
                    after = {i: received_bytes(p.pid) for i, p in procs.items()}
                    dt = time.monotonic() - t0
                finally:
                    fleet.pause()
        finally:
            for svc in procs.values():
                svc.stop()
    return [(after[i] - before[i]) / dt for i in ids]


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__, preset="bacf", fps=10.0)
    ap.add_argument("--streams", type=int, default=6, help="streams over the whole fleet")
    ap.add_argument("--instances", default="1,2,3", help="fleet sizes to measure")
    ap.add_argument("--seconds", type=float, default=20.0, help="the measured window")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from arcf.eval.environment import describe

    print(f"`python benchmarks/fanin.py {' '.join(argv or sys.argv[1:])}`".replace(" `", "`"))
    print(f"{time.strftime('%Y-%m-%d')}, {describe()}; {args.streams} streams of truck4_1 at "
          f"{args.fps:g} fps ({args.preset}), one session each, over the fleet\n")
    print("| instances | bytes/s each instance's main process received (min, max) |")
    print("| --- | --- |")
    for n in [int(x) for x in args.instances.split(",") if x]:
        rates = run(n, args.streams, args.fps, args.seconds, args.preset)
        print(f"| {n} | {min(rates):,.0f}, {max(rates):,.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

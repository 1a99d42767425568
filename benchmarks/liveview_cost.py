"""What the live view costs: ``arcf-view``'s CPU with nobody watching, one viewer and several,
on a 30 fps 1280x720 stream (JPEG frames, or H.264 units), next to the pictures it serves.

    python benchmarks/liveview_cost.py                   # JPEG, ~1 min
    python benchmarks/liveview_cost.py --encoding h264

A service (one worker, a ``bacf`` session) tracks the stream; ``arcf-view`` runs as its own
process, and its CPU time is read from /proc over each window. Viewers are HTTP clients doing
what the page does: long-polling ``frame.jpg`` and reading the results' event stream.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Sequence
from pathlib import Path

from _common import parser  # beside this script

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from arcf.client import TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.video import encode_video

TICK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime + stime


def viewer(url: str, stop: threading.Event, counts: list[int], index: int) -> None:
    """One page's traffic: the next picture once the last arrived; the results as SSE."""
    def events() -> None:
        with urllib.request.urlopen(url + "/results", timeout=30) as r:
            while not stop.is_set() and r.readline():
                pass

    threading.Thread(target=events, daemon=True).start()
    after = -1
    while not stop.is_set():
        with urllib.request.urlopen(f"{url}/frame.jpg?after={after}", timeout=30) as r:
            if r.status == 200:
                after = int(r.headers["X-Rendered"])
                r.read()
                counts[index] += 1


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser(__doc__, fps=30.0)
    ap.add_argument("--encoding", choices=("jpeg", "h264"), default="jpeg")
    ap.add_argument("--seconds", type=float, default=10.0, help="per window")
    ap.add_argument("--viewers", type=int, nargs="+", default=[0, 1, 4])
    args = ap.parse_args(argv)

    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    jpegs = [p.read_bytes() for p in seq.frames[:60]]
    data = (jpegs if args.encoding == "jpeg" else
            encode_video((decode_compressed(j) for j in jpegs), "h264", gop=30))
    port = free_port()
    stop = threading.Event()
    with ServiceProcess(workers=1) as service, \
            TrackingClient(connect=[service.endpoint]) as client:
        client.start("view", seq.init_box, preset="bacf")

        def publish() -> None:  # bounded: until stop, at most an hour
            t0, i = time.monotonic(), 0
            while not stop.is_set() and i < 3600 * args.fps:
                client.publish_frame("view", data=data[i % len(data)], encoding=args.encoding,
                                     seq=i)
                i += 1
                stop.wait(max(0.0, t0 + i / args.fps - time.monotonic()))

        threading.Thread(target=publish, daemon=True).start()
        view = subprocess.Popen(
            [sys.executable, "-m", "arcf.adapters.liveview", "--port", str(port), "-e",
             service.endpoint], stderr=subprocess.DEVNULL)
        try:
            time.sleep(3.0)  # started, connected
            url = f"http://127.0.0.1:{port}/api/streams/view"
            print(f"arcf-view on a {args.fps:g} fps 1280x720 {args.encoding} stream, "
                  f"--max-fps 5 --max-width 960, {args.seconds:g} s per window; "
                  f"{time.strftime('%Y-%m-%d')}, {describe()}:")
            print("| viewers | arcf-view CPU (% of a core) | pictures / s per viewer |")
            print("| ---: | ---: | ---: |")
            for n in args.viewers:
                quit_ = threading.Event()
                counts = [0] * n
                threads = [threading.Thread(target=viewer, args=(url, quit_, counts, k),
                                            daemon=True) for k in range(n)]
                for t in threads:
                    t.start()
                time.sleep(2.0)  # the watch starts, the first pictures flow
                c0, k0, t0 = cpu_seconds(view.pid), list(counts), time.monotonic()
                time.sleep(args.seconds)
                spent, dt = cpu_seconds(view.pid) - c0, time.monotonic() - t0
                rate = (sum(counts) - sum(k0)) / dt / n if n else 0.0
                print(f"| {n} | {100 * spent / dt:.1f} | {rate:.1f} |", flush=True)
                quit_.set()
                time.sleep(1.0)
        finally:
            stop.set()
            view.terminate()
            view.wait(timeout=10)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

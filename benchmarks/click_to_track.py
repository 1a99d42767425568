"""Click to track: from a box dragged in the live view to its first result and to the first
picture the view draws it on, repeated start / stop on a live stream.

    python benchmarks/click_to_track.py              # 20 boxes, ~1 min
    python benchmarks/click_to_track.py --boxes 50 --preset arcf-hc

A one-worker service and a 10 fps 1280x720 JPEG stream (wakeboard7, cycled) with no session;
``arcf-view --allow-control`` in this process (``--max-fps 5``). Each round does what the page
does on a drag: ``POST /api/streams/<stream>/sessions`` with the target's box; then it times
the reply (the session started), the session's first result at a station, and the first picture
the view renders with the session's box; then stops the session.
"""

from __future__ import annotations

import json
import sys
import threading
import time
import urllib.request
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from _common import parser  # beside this script

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from arcf.adapters.liveview import LiveView
from arcf.client import TrackingClient
from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.procs import ServiceProcess
from arcf.schemas import Result


def post(url: str, body: dict, token: str) -> dict:
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                 headers={"Content-Type": "application/json",
                                          "Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(req, timeout=30) as reply:
        return json.loads(reply.read())


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser(__doc__, preset="bacf")
    ap.add_argument("--boxes", type=int, default=20)
    args = ap.parse_args(argv)
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    data = [p.read_bytes() for p in seq.frames[:60]]
    gt = np.asarray(seq.groundtruth, dtype=float)
    stop = threading.Event()
    latest = [-1]  # the last frame published
    times: dict[str, list[float]] = {"reply": [], "first result": [], "first box drawn": []}
    with ServiceProcess(workers=1) as service, \
            TrackingClient(connect=[service.endpoint]) as camera, \
            TrackingClient(connect=[service.endpoint]) as station:

        def publish() -> None:  # 10 fps, bounded: at most 10 minutes
            for i in range(6000):
                if stop.wait(0.1):
                    return
                camera.publish_frame("cam", data=data[i % len(data)], seq=i)
                latest[0] = i

        threading.Thread(target=publish, daemon=True).start()
        view = LiveView(station, "127.0.0.1", 0, max_fps=5, max_width=960, allow_control=True)
        events = urllib.request.urlopen(view.url + "api/streams/cam/results", timeout=30)
        try:
            time.sleep(2.0)  # the stream flows and is watched
            watch = view.watches["cam"]
            for _ in range(args.boxes):
                shown = latest[0]  # the box drawn on the last frame (its true box)
                box = [float(v) for v in gt[shown % len(data)]]
                got: list[float] = []

                def heard(r: Result, got: list[float] = got) -> None:
                    if r.status.value != "stale":
                        got.append(time.perf_counter())

                results = station.results("cam", callback=heard)
                t0 = time.perf_counter()
                sid = post(view.url + "api/streams/cam/sessions",
                           {"box": box, "preset": args.preset, "frame_seq": shown},
                           view.control.token)["session_id"]
                times["reply"].append(time.perf_counter() - t0)
                deadline = time.monotonic() + 30
                while not got and time.monotonic() < deadline:
                    time.sleep(0.002)
                times["first result"].append(got[0] - t0)
                while time.monotonic() < deadline:
                    with watch.changed:
                        if any(r.session_id == sid for r in watch.drawn):
                            break
                        watch.changed.wait(timeout=0.5)
                times["first box drawn"].append(time.perf_counter() - t0)
                results.close()
                post(view.url + f"api/sessions/{sid}/stop", {}, view.control.token)
                time.sleep(0.5)
        finally:
            events.close()
            stop.set()
            view.close()
    print(f"# python benchmarks/click_to_track.py --boxes {args.boxes} --preset {args.preset}")
    print(f"# {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, {describe()}")
    print("| from the drag to | median (ms) | p95 (ms) | max (ms) |")
    print("| --- | ---: | ---: | ---: |")
    for name, values in times.items():
        a = 1e3 * np.asarray(values)
        print(f"| {name} | {np.median(a):.0f} | {np.percentile(a, 95):.0f} | {a.max():.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""A camera that stops and comes back: how soon ``arcf-ingest`` sends its video again.

    python benchmarks/camera_return.py                  # 5 trials, the camera away 5 s
    python benchmarks/camera_return.py --trials 3 --down-s 10

A 1280×720 30 fps H.264 camera (a shared sequence, libx264, keyframes every ``--gop``,
parameter sets before each) sends RTP on loopback (FFmpeg's muxer, PyAV). ``arcf-ingest``
(its ``Ingest``, with its defaults: a source silent 3 s is reopened after 0.25 s, then
twice as long each time up to 1 s) reads it as ``rtp://127.0.0.1:PORT`` and publishes to a
service's router; a station watches the stream's frames. Each trial: the camera sends for
3 s, stops for ``--down-s`` seconds (the ingest notices the silence and reopens the source
in its back-off), and a new camera process starts (its stream begins at a keyframe).
Measured from the new camera's first unit: the first frame at the station. It holds the
ingest's back-off (at most 1 s), FFmpeg's probing of a live source (1 s at most) and the
network; beside it, the same from the first camera's start, when the ingest was already
waiting (no back-off), and how many times the ingest reopened the source.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Any

from _common import parser, report, spread  # beside this script

from arcf.adapters.ingest import Ingest, parse_source
from arcf.client import TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.senders import VideoSender, free_rtp_port
from arcf.loadtools.video import encode_video
from arcf.loadtools.waiting import wait_until

#: what the table's middle column measures
FIRST_START = ("A first start: the ingest already waiting on the port when the camera starts "
               "(FFmpeg's probing of the stream and the network; no back-off).")


def trial(service: ServiceProcess, k: int, units: list[bytes], size: tuple[int, int],
          down_s: float) -> dict[str, Any]:
    port, stream = free_rtp_port(), f"cam{k}"
    arrivals: list[float] = []
    lock = threading.Lock()

    def arrived(_: Any) -> None:
        with lock:
            arrivals.append(time.monotonic())

    with TrackingClient(connect=[service.endpoint]) as client:
        watch = client.frames(stream, callback=arrived)
        ingest = Ingest(client, parse_source(f"rtp://127.0.0.1:{port}"), stream).start()
        try:
            t_first = time.monotonic()
            first = VideoSender(units, f"rtp://127.0.0.1:{port}", "rtp", size,
                                repeat=1000).start()
            wait_until(lambda: ingest.counts["published"] >= 30, timeout=60,
                       what="the camera's first second at the station")
            with lock:
                start_s = min(arrivals) - t_first
            time.sleep(3.0)  # the camera sends
            first.stop()
            reopened = ingest.counts["reopened"]
            time.sleep(down_s)  # away: the ingest notices and reopens in its back-off
            t_return = time.monotonic()
            second = VideoSender(units, f"rtp://127.0.0.1:{port}", "rtp", size,
                                 repeat=1000).start()
            # its first unit leaves at once (the sender's clock starts with it)
            wait_until(lambda: second.sent > 0, timeout=10, what="the new camera's first unit")
            wait_until(lambda: any(t > t_return for t in list(arrivals)), timeout=60,
                       what="the returned camera's video at the station")
            second.stop()
            with lock:
                back = min(t for t in arrivals if t > t_return)
            return {"down_s": down_s, "back_s": back - t_return, "start_s": start_s,
                    "reopened": ingest.counts["reopened"] - reopened,
                    "read_timeouts": ingest.counts["read_timeouts"]}
        finally:
            ingest.close()
            watch.close()


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--down-s", type=float, default=5.0, help="the camera away, seconds")
    ap.add_argument("--gop", type=int, default=10, help="keyframe interval, frames")
    ap.add_argument("--sequence", default="wakeboard7", help="a UAV123@10fps sequence")
    ap.add_argument("--json", type=Path, help="write every trial's figures here")
    args = ap.parse_args(argv)
    (sequence,) = load_dataset("uav123_10fps", sequences=[args.sequence])
    images = [decode_compressed(p.read_bytes()) for p in sequence.frames[:30]]
    units = encode_video(images, "h264", fps=30, gop=args.gop, repeat_headers=True)
    size = (images[0].shape[1], images[0].shape[0])
    service = ServiceProcess(workers=1)
    try:
        trials = [trial(service, k, units, size, args.down_s) for k in range(args.trials)]
    finally:
        service.stop()
    report("camera_return.py", argv,
           f"{args.trials} trials, RTP 1280×720 H.264 at 30 fps, keyframes every "
           f"{args.gop}, the camera away {args.down_s:g} s",
           ["camera back → its first frame at the station", "a first start, the same way",
            "source reopened while away"],
           [[spread([1e3 * t["back_s"] for t in trials], unit=" ms"),
             spread([1e3 * t["start_s"] for t in trials], unit=" ms"),
             spread([t["reopened"] for t in trials])]],
           FIRST_START, args.json, trials)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A box drawn between keyframes of an H.264 stream: the picture it lands on, and how soon
the session is live.

    python benchmarks/catch_up.py                          # groups of 10, 30 and 60 at 30 fps
    python benchmarks/catch_up.py --gops 30,90 --trials 5 --preset arcf-hc

One service (one worker, its embedded router). For each group length (``--gops``) a station
publishes a real sequence as 1280×720 H.264 (libx264, a keyframe every GOP frames, no
B-frames) at ``--fps``, nobody tracking it. After two groups, it clicks on the frame it has
just sent, at a phase of the group: ``last``, the frame before a keyframe (the worst case: a
whole group to decode again), or ``middle``. It starts a session with that ``frame_seq``.

Measured per trial: the frame of the session's first result (it must be the clicked one);
the time from the request to that result; the time to the first result about a frame sent
after the request (the session is on the live stream again) and that result's lag (its
arrival minus its frame's sending); and the time until a result comes within 100 ms of its
frame (caught up).
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Any

from _common import parser, report, spread  # beside this script

from arcf.client import TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.video import encode_video
from arcf.loadtools.waiting import wait_until

PHASES = ("last", "middle")
#: a result this soon after its frame was sent is live (three frame periods at 30 fps)
CAUGHT_UP_S = 0.1


def trial(service: ServiceProcess, stream: str, units: list[bytes], boxes: list[Any],
          gop: int, phase: str, preset: str, fps: float) -> dict[str, Any]:
    station = TrackingClient(connect=[service.endpoint])
    arrivals: list[tuple[float, Any]] = []
    watch = station.results(stream, callback=lambda r: arrivals.append((time.monotonic(), r)))
    sent_at: dict[int, float] = {}
    stop = threading.Event()

    def publish() -> None:
        for seq in range(int(fps * 120)):  # bounded: two minutes of video at most
            if stop.wait(1 / fps):
                return
            station.publish_frame(stream, data=units[seq % len(units)], encoding="h264",
                                  seq=seq)
            sent_at[seq] = time.monotonic()

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    want = gop - 1 if phase == "last" else gop // 2
    try:
        wait_until(lambda: len(sent_at) > 2 * gop and (len(sent_at) - 1) % gop == want,
                   timeout=60, what="the frame to click on")
        clicked = max(sent_at)
        t_request = time.monotonic()
        ack = station.start(stream, boxes[clicked % len(boxes)], preset=preset,
                            frame_seq=clicked)
        last_sent = max(sent_at)

        def mine() -> list[tuple[float, Any]]:
            return [(t, r) for t, r in list(arrivals) if r.session_id == ack.session_id
                    and r.status != "stale"]

        def caught_up() -> float | None:
            """When a result about a live frame first came within CAUGHT_UP_S of it."""
            return next((t for t, r in mine() if r.frame_seq > last_sent
                         and t - sent_at[r.frame_seq] <= CAUGHT_UP_S), None)

        wait_until(lambda: caught_up() is not None, timeout=60, what="the session caught up")
        first_t, first = mine()[0]
        live_t, live = next((t, r) for t, r in mine() if r.frame_seq > last_sent)
        caught_t = caught_up()
        assert caught_t is not None
        assert ack.session_id is not None
        station.stop(ack.session_id)
        return {
            "gop": gop, "phase": phase, "clicked": clicked,
            "first_frame": first.frame_seq, "first_status": first.status.value,
            "first_s": first_t - t_request, "live_s": live_t - t_request,
            "live_lag_s": live_t - sent_at[live.frame_seq], "caught_up_s": caught_t - t_request,
        }
    finally:
        stop.set()
        thread.join(timeout=5)
        watch.close()
        station.close()


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__, preset="arcf-h", fps=30.0)
    ap.add_argument("--gops", default="10,30,60", help="group lengths, in frames")
    ap.add_argument("--trials", type=int, default=3, help="trials per group length and phase")
    ap.add_argument("--sequence", default="wakeboard7", help="a UAV123@10fps sequence")
    ap.add_argument("--json", type=Path, help="write every trial's figures here")
    args = ap.parse_args(argv)
    (sequence,) = load_dataset("uav123_10fps", sequences=[args.sequence])
    images = [decode_compressed(p.read_bytes()) for p in sequence.frames]
    gops = [int(g) for g in args.gops.split(",") if g]
    trials = []
    service = ServiceProcess(workers=1)
    try:
        for gop in gops:
            n = max(gop, len(images) - len(images) % gop)  # loops back at a keyframe
            units = encode_video((images[i % len(images)] for i in range(n)), "h264",
                                 fps=int(args.fps), gop=gop)
            for phase in PHASES:
                for k in range(args.trials):
                    trials.append(trial(service, f"g{gop}-{phase}-{k}", units,
                                        list(sequence.groundtruth), gop, phase, args.preset,
                                        args.fps))
    finally:
        service.stop()
    rows = []
    for gop in gops:
        for phase in PHASES:
            mine = [t for t in trials if t["gop"] == gop and t["phase"] == phase]
            on = sum(t["first_frame"] == t["clicked"] and t["first_status"] == "initialized"
                     for t in mine)

            def ms(key: str, rows: list[dict[str, Any]] = mine) -> str:
                return spread([1e3 * t[key] for t in rows], unit=" ms")

            rows.append([str(gop), "the frame before a keyframe" if phase == "last"
                         else "mid-group", f"{on} of {len(mine)}", ms("first_s"), ms("live_s"),
                         ms("live_lag_s"), ms("caught_up_s")])
    report("catch_up.py", argv,
           f"{args.trials} trials per row, {args.preset} on {args.sequence} as 1280×720 "
           f"H.264 at {args.fps:g} fps",
           ["group", "clicked on", "first box on the clicked frame", "first box",
            "live again", "lag then", "caught up"], rows,
           "Times from the start request. Live again: the first result about a frame sent "
           "after it, and how long after its frame it came; caught up: the first result "
           f"within {1e3 * CAUGHT_UP_S:.0f} ms of its frame.",
           args.json, trials)
    return 0


if __name__ == "__main__":
    sys.exit(main())

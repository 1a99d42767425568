"""A lone instance restarted with its state file: how soon the pilot's track is back.

    python benchmarks/restart.py                     # SIGTERM and SIGKILL, 5 trials each
    python benchmarks/restart.py --trials 3 --signals kill --json restart.json

Each trial: one service (one worker, its embedded router, ``--state-file``), a station
publishing a real sequence at ``--fps`` and tracking it with ``--preset``; after ``--warm-s``
seconds the service gets the signal, and after ``--down-s`` seconds it is started again with
the same state file on the same port. Measured from the new process's start: its ready line,
the session's first ``resumed`` result at the station (the instance resumes what it owns as
it joins, before its ready line), and the first ``tracking`` one after it; and the frames
the station sent while the service was away or starting, which no result answered.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from _common import parser, report, spread  # beside this script

from arcf.client import TrackingClient
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.waiting import wait_until

SIGNALS = {"term": signal.SIGTERM, "kill": signal.SIGKILL}


def trial(sequence: Any, how: str, preset: str, fps: float, warm_s: float,
          down_s: float) -> dict[str, Any]:
    folder = Path(tempfile.mkdtemp(prefix="arcf-restart-"))
    state, endpoint = folder / "sessions.jsonl", f"tcp/127.0.0.1:{free_port()}"
    args = ("--state-file", str(state))
    service = ServiceProcess(*args, listen=endpoint, workers=1)
    data = [p.read_bytes() for p in sequence.frames]
    station = TrackingClient(connect=[endpoint])
    arrivals: list[tuple[float, Any]] = []
    watch = station.results("cam1", callback=lambda r: arrivals.append((time.monotonic(), r)))
    stop = threading.Event()
    sent: list[int] = []

    def publish() -> None:
        for seq in range(int(fps * (warm_s + down_s + 120))):  # bounded
            if stop.wait(1 / fps):
                return
            station.publish_frame("cam1", data=data[seq % len(data)], seq=seq)
            sent.append(seq)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        wait_until(lambda: sent, timeout=30, what="the first frame")
        ack_seq = sent[-1] + 1
        ack = station.start("cam1", sequence.groundtruth[ack_seq % len(data)], preset=preset,
                            frame_seq=ack_seq)
        time.sleep(warm_s)
        wait_until(lambda: state.exists(), timeout=30, what="the state file")
        if how == "term":
            service.stop()
        else:
            service.kill()
        t_down = time.monotonic()
        time.sleep(down_s)
        t_start = time.monotonic()
        service = ServiceProcess(*args, listen=endpoint, workers=1)
        t_ready = time.monotonic()

        def first(status: str, after: float) -> float | None:
            return next((t for t, r in list(arrivals) if t > after and r.status == status
                         and r.session_id == ack.session_id), None)

        wait_until(lambda: first("tracking", t_start) is not None, timeout=60,
                   what="tracking again")
        resumed, tracking = first("resumed", t_start), first("tracking", t_start)
        answered = {r.frame_seq for _, r in list(arrivals)}
        tracked = [s for s in sent if s > ack_seq]  # the session's frames
        gap = [s for s in tracked if s not in answered]
        return {
            "signal": how,
            "ready_s": t_ready - t_start,
            "resumed_s": None if resumed is None else resumed - t_start,
            "tracking_s": None if tracking is None else tracking - t_start,
            "down_s": t_start - t_down,
            "frames_unanswered": len([s for s in gap if s < tracked[-1]]),
        }
    finally:
        stop.set()
        thread.join(timeout=5)
        watch.close()
        station.close()
        service.stop()
        subprocess.run(["rm", "-rf", str(folder)], check=False)


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__, preset="arcf-h", fps=10.0)
    ap.add_argument("--trials", type=int, default=5, help="trials per signal")
    ap.add_argument("--signals", default="term,kill", help="term, kill or both")
    ap.add_argument("--sequence", default="wakeboard7", help="a UAV123@10fps sequence")
    ap.add_argument("--warm-s", type=float, default=3.0, help="tracking before the signal")
    ap.add_argument("--down-s", type=float, default=2.0, help="the service away")
    ap.add_argument("--json", type=Path, help="write every trial's figures here")
    args = ap.parse_args(argv)
    (sequence,) = load_dataset("uav123_10fps", sequences=[args.sequence])
    hows = [h for h in args.signals.split(",") if h]
    trials = [trial(sequence, how, args.preset, args.fps, args.warm_s, args.down_s)
              for how in hows for _ in range(args.trials)]
    rows = []
    for how in hows:
        mine = [t for t in trials if t["signal"] == how]

        def ms(key: str, rows: list[dict[str, Any]] = mine) -> str:
            return spread([1e3 * t[key] for t in rows if t[key] is not None], unit=" ms")

        rows.append([f"SIG{how.upper()}", ms("ready_s"), ms("resumed_s"), ms("tracking_s"),
                     spread([t["frames_unanswered"] for t in mine])])
    report("restart.py", argv,
           f"{args.trials} trials per signal, {args.preset} on {args.sequence} at "
           f"{args.fps:g} fps, the service away {args.down_s:g} s",
           ["signal", "ready line", "first `resumed` result", "first `tracking` result",
            "frames unanswered"], rows,
           "Times from the new process's start. Unanswered: the frames sent while the "
           "service was away or starting.",
           args.json, trials)
    return 0


if __name__ == "__main__":
    sys.exit(main())

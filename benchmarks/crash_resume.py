"""How fast a session resumes when its worker process dies, and what the other streams lose.

    python benchmarks/crash_resume.py                  # 8 kills, about 3 minutes on 2 cores
    python benchmarks/crash_resume.py --kills 20 --fps 30 --preset arcf-hc

One ``arcf-service`` (two workers) on loopback, two streams of real UAV123@10fps frames
(wakeboard7) at ``--fps`` each, one session each; least-loaded placement puts them on
different workers. Then, ``--kills`` times: one worker is killed (SIGKILL and SIGSEGV in
turn), and the benchmark measures, at the station, the time from the kill to the killed
stream's first ``resumed`` result, and counts the frames of the other stream that got no
result from the kill until the replacement worker was ready (results are matched to frames
by number). Before the next kill,
the replacement worker's liveliness token must be up, and one session starts again so that
each worker has one stream. Quarantine is off (each kill is a strike against the killed
stream).
"""

from __future__ import annotations

import datetime
import os
import shlex
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence, Sized
from typing import Any

import numpy as np
from _common import parser  # beside this script

from arcf.client import TrackingClient
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess, worker_pids
from arcf.loadtools.system import machine
from arcf.schemas import KeySpace, Result
from arcf.service.scrape import by_label, fetch

STREAMS = ("crash-a", "crash-b")
KEYS = KeySpace()


class Feed:
    """One stream's frames at a steady rate, and the results that came back (by frame)."""

    def __init__(self, client: TrackingClient, stream: str, data: list[bytes], fps: float):
        self.client, self.stream, self.data, self.period = client, stream, data, 1 / fps
        self.sent: dict[int, float] = {}
        self.results: dict[int, tuple[float, Result]] = {}
        self.resumed: list[float] = []
        self.stop = threading.Event()
        self.sub = client.results(stream, callback=self._on_result)
        self.thread = threading.Thread(target=self._run, name=f"feed-{stream}", daemon=True)

    def _on_result(self, r: Result) -> None:
        now = time.monotonic()
        if r.frame_seq is not None and r.status != "stale":
            self.results.setdefault(r.frame_seq, (now, r))
        if r.status == "resumed":
            self.resumed.append(now)

    def _run(self) -> None:
        t_next, i = time.monotonic(), 0
        while not self.stop.is_set() and i < 1_000_000:
            self.client.publish_frame(self.stream, data=self.data[i % len(self.data)], seq=i)
            self.sent[i] = time.monotonic()
            i += 1
            t_next += self.period
            time.sleep(max(0.0, t_next - time.monotonic()))

    def lost(self, t0: float, t1: float) -> int:
        """Frames sent within [t0, t1] with no result (the caller gave them time to get one)."""
        return sum(1 for seq, t in list(self.sent.items())
                   if t0 <= t <= t1 and seq not in self.results)


def workers_up(client: TrackingClient) -> int:
    return sum(1 for r in client.session.liveliness().get(KEYS.all_workers(), timeout=2.0)
               if r.ok is not None)


def longer_than(items: Sized, n: int) -> Callable[[], bool]:
    return lambda: len(items) > n


def resumed_after(feed: Feed, t: float) -> Callable[[], bool]:
    return lambda: any(r > t for r in feed.resumed)


def wait(cond: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise SystemExit(f"crash_resume: {what} did not happen within {timeout:.0f} s")
        time.sleep(0.02)


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser(__doc__, preset="arcf-h", fps=30.0)
    ap.add_argument("--kills", type=int, default=8)
    args = ap.parse_args(argv)
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    data = [p.read_bytes() for p in seq.frames]
    print(f"$ python {shlex.join(['benchmarks/crash_resume.py', *(argv or sys.argv[1:])])}")
    m = machine()
    print(f"{datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z}, nproc {m['nproc']}, "
          f"{m['cpu']}, {m['software']}, load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print(f"2 workers, 2 streams at {args.fps:g} fps, preset {args.preset}, "
          f"{args.kills} kills", flush=True)
    svc = ServiceProcess("--quarantine-after", "0", workers=2)
    resume_s: list[float] = []
    lost_other: list[int] = []
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            feeds = {s: Feed(client, s, data, args.fps) for s in STREAMS}
            notices: list[tuple[float, str]] = []
            def noticed(stream: str) -> Callable[[Any], None]:
                return lambda _sample: notices.append((time.monotonic(), stream))

            subs = [client.session.declare_subscriber(KEYS.errors(s), noticed(s))
                    for s in STREAMS]
            sessions: dict[str, str] = {}
            for s, feed in feeds.items():
                sessions[s] = str(client.start(s, seq.init_box, preset=args.preset,
                                               frame_seq=0, timeout=30).session_id)
                feed.thread.start()
            wait(lambda: all(len(f.results) > 10 for f in feeds.values()), 60, "tracking")
            for k in range(args.kills):
                if k:
                    # both sessions are on the survivor now: one starts again, on the
                    # replacement (least-loaded placement), so that each worker has one
                    s = STREAMS[k % 2]
                    client.stop(sessions[s])
                    sessions[s] = str(client.start(s, seq.init_box, preset=args.preset,
                                                   timeout=30).session_id)
                    n = len(feeds[s].results)
                    wait(longer_than(feeds[s].results, n + 10), 60, "tracking")
                sig = (signal.SIGKILL, signal.SIGSEGV)[k % 2]
                victim = min(worker_pids(svc.proc.pid))
                n_notices = len(notices)
                t_kill = time.monotonic()
                os.kill(victim, sig)
                wait(longer_than(notices, n_notices), 30, "a notice on a stream")
                stream = notices[n_notices][1]
                other = next(s for s in STREAMS if s != stream)
                wait(resumed_after(feeds[stream], t_kill), 60, f"{stream} resumed")
                resumed = min(r for r in feeds[stream].resumed if r > t_kill) - t_kill
                wait(lambda: workers_up(client) == 2 and len(worker_pids(svc.proc.pid)) == 2,
                     180, "the replacement worker ready")
                t_ready = time.monotonic()
                time.sleep(2.0)  # the other stream's frames of the episode get their results
                # from the kill until the replacement is ready (its start-up takes CPU too)
                lost = feeds[other].lost(t_kill, t_ready)
                resume_s.append(resumed)
                lost_other.append(lost)
                print(f"kill {k + 1} ({sig.name}): {stream} resumed after "
                      f"{1e3 * resumed:.0f} ms; {other} lost {lost} frames", flush=True)
            for feed in feeds.values():
                feed.stop.set()
                feed.thread.join(timeout=10)
            for sub in subs:
                sub.undeclare()
            assert svc.metrics_url is not None  # the harness's default
            causes = by_label(fetch(svc.metrics_url), "arcf_worker_deaths_total", "cause")
    finally:
        svc.stop()
    v = 1e3 * np.asarray(resume_s)
    print("\n| measured | median / min / max |\n| --- | --- |")
    print(f"| kill -> the killed stream's first `resumed` result | {np.median(v):.0f} / "
          f"{v.min():.0f} / {v.max():.0f} ms |")
    print(f"| frames of the other stream without a result, kill to replacement ready | "
          f"{np.median(lost_other):.0f} / {min(lost_other)} / {max(lost_other)} |")
    print(f"| deaths counted by cause | {', '.join(f'{c} {n:.0f}' for c, n in causes.items())} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

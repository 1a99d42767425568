"""A stream that stops: how long until the service says so (its ``stale`` result), and until
``arcf-mavlink``'s ``CAMERA_TRACKING_IMAGE_STATUS`` leaves ACTIVE.

A service (1 worker, ``stale_after_s`` as given, 0.8 s by default), a station publishing
wakeboard7's JPEG frames at ``--fps``, ``arcf-mavlink`` (its own timeout the same) on a loopback
UDP port, and a ground station played with pymavlink that asks for the status at
``--status-hz`` and tracks the target's ground-truth rectangle. Then, ``--pauses`` times: two
seconds of frames, and the station stops; measured from the last frame's put (the station's
clock, one process: monotonic):

* to the session's ``stale`` result arriving at the station;
* on the service's own clock, from the last frame's arrival (``received_ts_ns`` of its result)
  to the notice's publication (``published_ts_ns``): what the worker adds to the setting;
* to the first status the ground station receives that is not ACTIVE for want of a box
  (ERROR, no target data: a lost target is ERROR with its box), and which side said so
  first: the service's notice or the adapter's own timeout (from its ``STATUSTEXT``).

Then ``--hangs`` times the service itself goes silent while the frames go on (its worker
SIGSTOPped, then SIGCONTed): from the last result's arrival to the first status that is not
ACTIVE, the adapter's own timeout.

    python benchmarks/stale_stream.py                     # ~1 min
    python benchmarks/stale_stream.py --stale-after-s 0.5 --status-hz 50
"""

from __future__ import annotations

import datetime
import logging
import os
import shlex
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from _common import parser  # beside this script

os.environ.setdefault("MAVLINK20", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from pymavlink import mavutil

from arcf.adapters.mavlink import CameraConfig, MavlinkCameras
from arcf.client import TrackingClient
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.system import machine

mav = mavutil.mavlink
W, H = 1280, 720
STREAM = "cam1"


class Station:
    """The frame publisher (paused and resumed on demand), the results as they arrive, and a
    MAVLink ground station receiving the camera's statuses and texts."""

    def __init__(self, service: ServiceProcess, port: int, fps: float, status_hz: float,
                 data: list[bytes]) -> None:
        self.client = TrackingClient(connect=[service.endpoint], frame_congestion="block")
        self.data, self.period = data, 1.0 / fps
        self.flowing, self.paused, self._stop = threading.Event(), threading.Event(), False
        #: (seq, monotonic time of its put)
        self.sent: list[tuple[int, float]] = []
        #: (monotonic arrival, Result)
        self.results: list[tuple[float, Any]] = []
        self.sub = self.client.results(STREAM, callback=lambda r: self.results.append(
            (time.monotonic(), r)))
        #: (monotonic arrival, message) of statuses and texts from the camera
        self.mavlink: list[tuple[float, Any]] = []
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                               source_component=190)
        self.status_hz = status_hz
        self._threads = [threading.Thread(target=f, daemon=True)
                         for f in (self._publish, self._listen)]
        for t in self._threads:
            t.start()

    def _publish(self) -> None:
        seq = 0
        while not self._stop:
            if not self.flowing.is_set():
                self.paused.set()
                self.flowing.wait()
                self.paused.clear()
                continue
            t = time.monotonic()
            self.client.publish_frame(STREAM, data=self.data[seq % len(self.data)], seq=seq)
            self.sent.append((seq, t))
            seq += 1
            time.sleep(max(0.0, t + self.period - time.monotonic()))

    def _listen(self) -> None:
        next_beat = 0.0
        while not self._stop:
            now = time.monotonic()
            if now >= next_beat:
                self.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                             0)
                next_beat = now + 0.5
            msg = self.conn.recv_match(type=["CAMERA_TRACKING_IMAGE_STATUS", "STATUSTEXT"],
                                       blocking=True, timeout=0.02)
            if msg is not None:
                self.mavlink.append((time.monotonic(), msg))

    def command(self, command: int, *params: float) -> None:
        p = [*params, *[0.0] * (7 - len(params))]
        self.conn.mav.command_long_send(1, 100, command, 0, *p)

    def statuses(self, after: float) -> list[tuple[float, Any]]:
        return [(t, m) for t, m in list(self.mavlink)
                if t > after and m.get_type() == "CAMERA_TRACKING_IMAGE_STATUS"]

    def texts(self, after: float) -> list[str]:
        return [m.text for t, m in list(self.mavlink) if t > after and m.get_type() == "STATUSTEXT"]

    def close(self) -> None:
        self._stop = True
        self.flowing.set()
        for t in self._threads:
            t.join(timeout=5)
        self.sub.close()
        self.client.close()
        self.conn.close()


def wait(predicate: Any, timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = predicate()
        if got:
            return got
        time.sleep(0.005)
    raise RuntimeError(f"no {what} within {timeout} s")


def stale(status: Any) -> bool:
    """A status that is not ACTIVE for want of a current box (ERROR, no target data); a lost
    target is ERROR too, but with its box."""
    return (not status.tracking_status & mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
            and status.target_data != mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS)


def tracked_again(st: Station, since: float) -> None:
    """Frames flowing for two seconds, and a status with a box after ``since``."""
    n = len(st.sent)
    wait(lambda: len(st.sent) >= n + round(2.0 / st.period), 30, "two seconds of frames")
    wait(lambda: [m for _, m in st.statuses(since)
                  if m.target_data == mav.CAMERA_TRACKING_TARGET_DATA_IN_STATUS], 30,
         "status with a box")


def pause(st: Station) -> dict[str, Any]:
    """The stream stops once; what each side took to say so."""
    st.flowing.clear()
    st.paused.wait()
    seq, t_last = st.sent[-1]
    notice = wait(lambda: [(t, r) for t, r in list(st.results)
                           if t > t_last and r.status.value == "stale"], 30, "stale notice")[0]
    answer = wait(lambda: [(t, r) for t, r in list(st.results)
                           if r.frame_seq == seq and r.track_state], 30, "last result")[0]
    status = wait(lambda: [(t, m) for t, m in st.statuses(t_last) if stale(m)], 30,
                  "status that is not ACTIVE")[0]
    text = wait(lambda: [x for x in st.texts(t_last) if x.startswith("tracking stale")], 10,
                "STATUSTEXT")[0]
    t_notice, r_notice = notice
    assert r_notice.frame_seq == seq, (r_notice.frame_seq, seq)
    return {"seq": seq,
            "notice_s": t_notice - t_last,
            "service_s": (r_notice.published_ts_ns - answer[1].received_ts_ns) / 1e9,
            "not_active_s": status[0] - t_last,
            "said_by": "adapter" if "no result from" in text else "service"}


def hang(st: Station, worker: int) -> dict[str, Any]:
    """The service silent (its worker stopped) while frames go on; the adapter's timeout."""
    os.kill(worker, signal.SIGSTOP)
    try:
        t_stop = time.monotonic()
        t_last = max(t for t, r in list(st.results) if r.track_state)
        status = wait(lambda: [(t, m) for t, m in st.statuses(t_stop) if stale(m)], 30,
                      "status that is not ACTIVE")[0]
    finally:
        os.kill(worker, signal.SIGCONT)
    return {"not_active_s": status[0] - t_last}


def figures(values: list[float]) -> str:
    v = 1e3 * np.asarray(values)
    return f"{np.median(v):.0f} / {v.min():.0f} / {v.max():.0f} ms"


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser(__doc__, preset="bacf", fps=10.0)
    ap.add_argument("--stale-after-s", type=float, default=0.8)
    ap.add_argument("--status-hz", type=float, default=10.0)
    ap.add_argument("--pauses", type=int, default=8)
    ap.add_argument("--hangs", type=int, default=4)
    args = ap.parse_args(argv)
    # its warnings are what is measured here
    logging.getLogger("arcf.adapters.mavlink").setLevel(logging.ERROR)
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    data = [p.read_bytes() for p in seq.frames]
    gt = np.asarray(seq.groundtruth)
    print(f"$ python {shlex.join(['benchmarks/stale_stream.py', *(argv or sys.argv[1:])])}")
    m = machine()
    print(f"{datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z}, nproc {m['nproc']}, "
          f"{m['cpu']}, {m['software']}, load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print(f"stale_after_s {args.stale_after_s:g} (service and adapter), {args.fps:g} fps, "
          f"status at {args.status_hz:g} Hz, preset {args.preset}")
    service = ServiceProcess("--stale-after-s", str(args.stale_after_s), workers=1)
    port = free_port()
    endpoint_client = TrackingClient(connect=[service.endpoint])
    endpoint = MavlinkCameras(endpoint_client, f"udpin:127.0.0.1:{port}",
                              [CameraConfig(STREAM, 100)], preset=args.preset,
                              status_interval_s=1.0 / args.status_hz,
                              stale_after_s=args.stale_after_s).start()
    st = Station(service, port, args.fps, args.status_hz, data)
    try:
        st.flowing.set()
        wait(lambda: endpoint.cameras[0].last_frame is not None and endpoint.link_up, 30,
             "a frame at the camera")
        st.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL,
                   mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS, 1e6 / args.status_hz)
        frame = endpoint.cameras[0].last_frame
        assert frame is not None  # waited for above
        x, y, w, h = gt[frame.seq % len(data)]
        st.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, (x - 1) / W, (y - 1) / H,
                   (x - 1 + w) / W, (y - 1 + h) / H)
        pauses = []
        for k in range(args.pauses):
            t0 = time.monotonic()
            st.flowing.set()
            tracked_again(st, t0)
            p = pause(st)
            pauses.append(p)
            print(f"pause {k + 1}: last frame {p['seq']}: stale notice at the station "
                  f"{1e3 * p['notice_s']:.0f} ms, on the service's clock "
                  f"{1e3 * p['service_s']:.0f} ms, status not ACTIVE {1e3 * p['not_active_s']:.0f} "
                  f"ms (first said by the {p['said_by']})", flush=True)
        (worker,) = service.workers
        hangs = []
        st.flowing.set()
        for k in range(args.hangs):
            tracked_again(st, time.monotonic())
            h_ = hang(st, worker)
            hangs.append(h_)
            print(f"hang {k + 1}: last result -> status not ACTIVE "
                  f"{1e3 * h_['not_active_s']:.0f} ms", flush=True)
        said = {who: sum(p["said_by"] == who for p in pauses) for who in ("service", "adapter")}
        print("\n| measured (median / min / max) | |\n| --- | --- |")
        print(f"| last frame put -> `stale` result at the station | "
              f"{figures([p['notice_s'] for p in pauses])} |")
        print(f"| last frame's arrival -> notice published (service clock) | "
              f"{figures([p['service_s'] for p in pauses])} |")
        print(f"| last frame put -> first MAVLink status not ACTIVE | "
              f"{figures([p['not_active_s'] for p in pauses])} |")
        print(f"| service silent: last result -> first status not ACTIVE | "
              f"{figures([h_['not_active_s'] for h_ in hangs])} |")
        print(f"\n{len(pauses)} pauses (first said by the service {said['service']}, by the "
              f"adapter's own timeout {said['adapter']}), {len(hangs)} hangs; endpoint counts "
              f"{dict(endpoint.counts)}")
    finally:
        st.close()
        endpoint.close()
        endpoint_client.close()
        service.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The MAVLink path: what ``arcf-mavlink`` adds between the service's results and a ground
station, and the endpoint driven by MAVProxy, an independent ground-station program.

1. **Added latency.** A service, a station publishing a real sequence at 10 fps (its JPEG
   frames; with ``--encoding h264`` H.264 access units as SDK frames, with ``--encoding
   video-key`` the same units as CDR ``CompressedVideo`` on ``video/<stream>/stream``, whose
   picture size the endpoint reads from the keyframes), ``arcf-mavlink`` on a loopback UDP
   port and a ground station played with pymavlink, which asks for
   ``CAMERA_TRACKING_IMAGE_STATUS`` at ``--status-hz`` and starts tracking with
   ``MAV_CMD_CAMERA_TRACK_RECTANGLE``. Every status received is matched to the result whose
   box it carries (received by the same process on the results key); printed: the delay
   from the result to the first status carrying it, and from the frame's capture to it.
2. **MAVProxy** (``--mavproxy``, needs ``.venv-mavproxy``, made by ``--setup-mavproxy``:
   MAVProxy from PyPI without its GUI dependencies). MAVProxy connects to the endpoint as a
   ground station would, and its own ``long`` command sends the track, status-request and stop
   commands; its console output (the acknowledgements it decoded) is printed.

    python benchmarks/mavlink_path.py                      # ~40 s
    python benchmarks/mavlink_path.py --encoding video-key
    python benchmarks/mavlink_path.py --mavproxy --setup-mavproxy
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from pymavlink import mavutil

from arcf.adapters.mavlink import CameraConfig, MavlinkCameras
from arcf.client import TrackingClient
from arcf.client.foxglove import compressed_video
from arcf.client.media.images import decode_compressed
from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.video import encode_video
from arcf.schemas import Result

ROOT = Path(__file__).resolve().parents[1]
MAVPROXY_VENV = ROOT / ".venv-mavproxy"
mav = mavutil.mavlink
W, H = 1280, 720


def setup_mavproxy() -> Path:
    """MAVProxy without its GUI, map and 3-D dependencies (vtk, wxPython, a second OpenCV):
    the console and the ``long`` command need only pymavlink and a few small packages."""
    python = MAVPROXY_VENV / "bin" / "python"
    if not python.exists():
        subprocess.run([sys.executable, "-m", "venv", str(MAVPROXY_VENV)], check=True)
        pip = [str(python), "-m", "pip", "install", "-q"]
        subprocess.run([*pip, "--no-deps", "MAVProxy==1.8.75"], check=True)
        subprocess.run([*pip, "pymavlink", "pyserial", "defusedxml", "numpy", "pynmeagps"],
                       check=True)
    return MAVPROXY_VENV / "bin" / "mavproxy.py"


class Rig:
    """Service, frame publisher (10 fps, the sequence looped) and the MAVLink endpoint."""

    def __init__(self, sequence: str, status_hz: float, encoding: str = "jpeg") -> None:
        (self.seq,) = load_dataset("uav123_10fps", sequences=[sequence])
        self.service = ServiceProcess(workers=1)
        self.port = free_port()
        self.publisher = TrackingClient(connect=[self.service.endpoint],
                                        frame_congestion="block")
        self.endpoint_client = TrackingClient(connect=[self.service.endpoint])
        self.endpoint = MavlinkCameras(self.endpoint_client, f"udpin:127.0.0.1:{self.port}",
                                       [CameraConfig("cam1", 100)],
                                       status_interval_s=1.0 / status_hz).start()
        self.results: list[tuple[float, Result]] = []
        self.sub = self.publisher.results(
            "cam1", callback=lambda r: self.results.append((time.monotonic(), r)))
        self._stop = threading.Event()
        self.encoding = encoding
        self.last_sent = -1  # the sequence's frame the camera sent last
        data = [p.read_bytes() for p in self.seq.frames]
        if encoding != "jpeg":  # a camera's H.264: a keyframe with its headers every 10
            data = encode_video((decode_compressed(d) for d in data), "h264", fps=10, gop=10,
                                repeat_headers=True)
        self._thread = threading.Thread(target=self._publish, args=(data,), daemon=True)
        self._thread.start()

    def _publish(self, data: list[bytes]) -> None:
        for i in range(1200):  # bounded: 2 minutes at 10 fps
            if self._stop.is_set():
                return
            unit = data[i % len(data)]
            if self.encoding == "video-key":
                self.publisher.session.put("video/cam1/stream",
                                           compressed_video(unit, "h264", time.time_ns()))
            elif self.encoding == "h264":
                self.publisher.publish_frame("cam1", data=unit, encoding="h264", seq=i)
            else:
                self.publisher.publish_frame("cam1", data=unit, seq=i)
            self.last_sent = i
            time.sleep(0.1)

    def gt_rectangle(self) -> tuple[float, float, float, float]:
        x, y, w, h = np.asarray(self.seq.groundtruth)[self.last_sent % len(self.seq.frames)]
        return (x - 1) / W, (y - 1) / H, (x - 1 + w) / W, (y - 1 + h) / H

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.sub.close()
        self.endpoint.close()
        self.endpoint_client.close()
        self.publisher.close()
        self.service.stop()


def latency(rig: Rig, seconds: float, status_hz: float) -> None:
    station = mavutil.mavlink_connection(f"udpout:127.0.0.1:{rig.port}", source_system=255,
                                         source_component=190)
    station.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    while rig.endpoint.cameras[0].last_frame is None:
        time.sleep(0.05)
    station.mav.command_long_send(1, 100, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                  mav.MAVLINK_MSG_ID_CAMERA_TRACKING_IMAGE_STATUS,
                                  1e6 / status_hz, 0, 0, 0, 0, 0)
    station.mav.command_long_send(1, 100, mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0,
                                  *rig.gt_rectangle(), 0, 0, 0)
    statuses: list[tuple[float, Any]] = []  # pymavlink messages (untyped)
    end = time.monotonic() + seconds
    next_beat = 0.0
    while time.monotonic() < end:
        now = time.monotonic()
        if now >= next_beat:
            station.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            next_beat = now + 1.0
        msg = station.recv_match(type="CAMERA_TRACKING_IMAGE_STATUS", blocking=True,
                                 timeout=0.05)
        if msg is not None and msg.tracking_status != mav.CAMERA_TRACKING_STATUS_FLAGS_IDLE:
            statuses.append((time.monotonic(), msg))
    station.close()
    delays, ages, unmatched = [], [], 0
    first_seen: set[int] = set()
    for t, s in statuses:
        box = np.array([s.rec_top_x * W + 1, s.rec_top_y * H + 1,
                        (s.rec_bottom_x - s.rec_top_x) * W, (s.rec_bottom_y - s.rec_top_y) * H])
        match = [(tr, r) for tr, r in rig.results
                 if r.track_state is not None and np.abs(np.array(r.box) - box).max() < 0.05]
        if not match:
            unmatched += 1
            continue
        tr, r = match[-1]
        if r.frame_seq in first_seen:
            continue  # the same result again (the status repeats until the next one)
        first_seen.add(r.frame_seq)
        delays.append(1e3 * (t - tr))
        ages.append((time.time_ns() - 1e9 * (time.monotonic() - t) - r.capture_ts_ns) / 1e6)
    d, a = np.array(delays), np.array(ages)
    print(f"{rig.encoding} frames; status at {status_hz:g} Hz for {seconds:g} s: "
          f"{len(statuses)} statuses, "
          f"{len(d)} results carried, {unmatched} unmatched")
    print(f"  result on its key -> first status carrying it: median {np.median(d):.1f} ms, "
          f"p95 {np.percentile(d, 95):.1f} ms, max {d.max():.1f} ms")
    print(f"  frame capture -> that status: median {np.median(a):.1f} ms, "
          f"p95 {np.percentile(a, 95):.1f} ms")


def drive_with_mavproxy(rig: Rig, mavproxy: Path) -> None:
    while rig.endpoint.cameras[0].last_frame is None:
        time.sleep(0.05)
    x0, y0, x1, y1 = rig.gt_rectangle()
    commands = ";".join([
        "set target_system 1", "set target_component 100",
        "long REQUEST_MESSAGE 259",
        "long SET_MESSAGE_INTERVAL 275 200000",
        f"long CAMERA_TRACK_RECTANGLE {x0:.4f} {y0:.4f} {x1:.4f} {y1:.4f}",
        "long CAMERA_TRACK_RECTANGLE 0.5 0.5 0.4 0.6",
        "long CAMERA_TRACK_POINT 0.5 0.5 0.02",
        "long CAMERA_STOP_TRACKING",
    ])
    proc = subprocess.Popen(
        [str(MAVPROXY_VENV / "bin" / "python"), str(mavproxy),
         f"--master=udpout:127.0.0.1:{rig.port}", "--non-interactive", "--nowait",
         "--source-system=255", "--source-component=190", f"--cmd={commands}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd="/tmp")
    try:
        out, _ = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.terminate()
        out, _ = proc.communicate(timeout=5)
    print("MAVProxy 1.8.75 (`long` commands), its console:")
    for line in out.splitlines():
        if any(k in line for k in ("COMMAND_ACK", "ACK", "STATUSTEXT", "camera", "Got",
                                   "cam1", "no frames", "bottom-right", "Detected")):
            print("  " + line)
    print(f"endpoint counts: {dict(rig.endpoint.counts)}")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default="wakeboard7")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--status-hz", type=float, default=10.0)
    ap.add_argument("--mavproxy", action="store_true")
    ap.add_argument("--setup-mavproxy", action="store_true")
    ap.add_argument("--encoding", choices=("jpeg", "h264", "video-key"), default="jpeg")
    args = ap.parse_args(argv)
    print(f"# python benchmarks/mavlink_path.py {' '.join(argv or sys.argv[1:])}")
    print(f"# {time.strftime('%Y-%m-%d')}, {describe()}")
    rig = Rig(args.sequence, args.status_hz, args.encoding)
    try:
        if args.mavproxy:
            script = MAVPROXY_VENV / "bin" / "mavproxy.py"
            if args.setup_mavproxy:
                script = setup_mavproxy()
            drive_with_mavproxy(rig, script)
        else:
            latency(rig, args.seconds, args.status_hz)
    finally:
        rig.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The follow loop on a real clock with every real part in it: a virtual gimbal camera's views
(640x360 of a shared sequence's pictures) published at 10 fps to a one-worker service, the
pilot's rectangle on a real MAVLink link, ``arcf-mavlink``'s follower sending Gimbal Protocol
v2 rates, a simulated gimbal moving by the commands as they arrive. Printed per sequence: the
time from a frame's capture to the command its result caused arriving at the gimbal, when the
target's true centre first stays within 10 % of the view's centre, and its largest offset
after 3 s.

    python benchmarks/follow_service.py                     # about 30 s
    python benchmarks/follow_service.py --sequences truck4_2 --preset arcf-hc
"""

from __future__ import annotations

import datetime
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from _common import parser  # beside this script

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from arcf.adapters.gimbal import FollowSettings, GimbalFollower, GimbalTarget
from arcf.adapters.mavlink import CameraConfig, MavlinkCameras
from arcf.client import TrackingClient
from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.gimbalsim import SimulatedGimbal, VirtualCamera
from arcf.loadtools.groundstation import GroundStation
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.schemas import Result

mav = mavutil.mavlink
VIEW = (640, 360)
FPS = 10.0


def _record_causes(follower: GimbalFollower | None) -> list[int | None]:
    """Wraps the follower's result entry and send so that each rate command it sends is noted
    with the frame whose result caused it, in sending order (measurement only)."""
    assert follower is not None
    caused: list[int | None] = []
    current: list[int | None] = [None]
    send, on_result = follower.send, follower.on_result

    def noted_send(msg: Any) -> None:
        if msg.get_type() == "GIMBAL_MANAGER_SET_PITCHYAW":
            caused.append(current[0])
        send(msg)

    def noted_result(result: Result, size: tuple[int, int] | None, now: float) -> None:
        current[0] = result.frame_seq
        try:
            on_result(result, size, now)
        finally:
            current[0] = None

    follower.send = noted_send
    follower.on_result = noted_result  # type: ignore[method-assign]
    return caused


def run(service: ServiceProcess, name: str, preset: str, seconds: float) -> dict[str, float]:
    (seq,) = load_dataset("uav123_10fps", sequences=[name])
    gt = np.asarray(seq.groundtruth, dtype=float)
    first = seq.read_frame(0)
    cam = VirtualCamera((first.shape[1], first.shape[0]), VIEW)
    gimbal = SimulatedGimbal()
    x, y, w, h = gt[0]
    gimbal.yaw = (x - 1 + w / 2 - 0.25 * VIEW[0] - cam.world_size[0] / 2) / cam.px_per_deg
    gimbal.pitch = -(y - 1 + h / 2 + 0.2 * VIEW[1] - cam.world_size[1] / 2) / cam.px_per_deg
    port = free_port()
    target = GimbalTarget(1, 1, settings=FollowSettings(hfov_deg=cam.hfov_deg))
    latency: list[float] = []
    offsets: list[tuple[float, float, float]] = []  # (t, x, y)
    with TrackingClient(connect=[service.endpoint]) as camera, \
            TrackingClient(connect=[service.endpoint]) as adapter:
        endpoint = MavlinkCameras(adapter, f"udpin:127.0.0.1:{port}",
                                  [CameraConfig(name, 100, follow=target)], preset=preset,
                                  status_interval_s=0.0).start()
        station = GroundStation(port, 100)
        caused = _record_causes(endpoint.cameras[0].follower)
        try:
            deadline = time.monotonic() + 30
            while not endpoint.link_up and time.monotonic() < deadline:
                time.sleep(0.05)
            captured: dict[int, float] = {}  # frame -> when its view was taken
            seen = 0  # commands applied
            t0 = last = time.monotonic()
            k = 0
            while (now := time.monotonic()) - t0 < seconds:
                gimbal.step(now - last)
                last = now
                commands = station.since(0, "GIMBAL_MANAGER_SET_PITCHYAW")
                for c in commands[seen:]:  # as they arrived: the newest rules
                    gimbal.commanded = (math.degrees(c.yaw_rate), math.degrees(c.pitch_rate))
                seen = len(commands)
                i = min(len(seq) - 1, int((now - t0) * 10))  # the world at its own 10 fps
                view = cam.view(seq.read_frame(i), gimbal)
                _, jpeg = cv2.imencode(".jpg", view, [cv2.IMWRITE_JPEG_QUALITY, 90])
                captured[k] = now  # the view is of this instant
                camera.publish_frame(name, data=jpeg.tobytes(), seq=k,
                                     capture_ts_ns=time.time_ns())
                if k == 0:
                    while endpoint.cameras[0].last_frame is None:
                        time.sleep(0.01)
                    bx, by, bw, bh = cam.to_view(gt[0], gimbal)
                    station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, (bx - 1) / VIEW[0],
                                    (by - 1) / VIEW[1], (bx - 1 + bw) / VIEW[0],
                                    (by - 1 + bh) / VIEW[1])
                truth = cam.to_view(gt[i], gimbal)
                offsets.append((now - t0, (truth[0] - 1 + truth[2] / 2) / VIEW[0] - 0.5,
                                (truth[1] - 1 + truth[3] / 2) / VIEW[1] - 0.5))
                k += 1
                time.sleep(max(0.0, t0 + k / FPS - time.monotonic()))  # the camera's clock
            # capture to command: the j-th command to arrive is the j-th the follower sent
            # (one UDP link on loopback keeps their order), and the follower's send says which
            # frame's result caused it (None: a let-go between results, no frame to time)
            deadline = time.monotonic() + 5
            while len(station.since(0, "GIMBAL_MANAGER_SET_PITCHYAW")) < len(caused) and \
                    time.monotonic() < deadline:
                time.sleep(0.05)
            arrivals = [t for t, m in list(station.received)
                        if m.get_type() == "GIMBAL_MANAGER_SET_PITCHYAW"]
            latency = [t - captured[f] for t, f in zip(arrivals, caused, strict=False)
                       if f is not None and f in captured]
        finally:
            station.close()
            endpoint.close()
    t = np.array([o[0] for o in offsets])
    off = np.abs(np.array([o[1:] for o in offsets]))
    inside = off.max(axis=1) < 0.10
    settled = next((t[j] for j in range(len(t)) if inside[j:].all()), math.nan)
    return {"latency_ms": 1e3 * float(np.median(latency)) if latency else math.nan,
            "latency_p95_ms": 1e3 * float(np.percentile(latency, 95)) if latency else math.nan,
            "settled_s": float(settled), "after_3s": float(off[t >= 3.0].max()),
            "frames": len(offsets)}


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser(__doc__, preset="arcf-h")
    ap.add_argument("--sequences", default="truck4_1,wakeboard10")
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args(argv)
    print(f"# python benchmarks/follow_service.py {' '.join(argv or sys.argv[1:])}")
    print(f"# {datetime.date.today()}, {describe()}; real clock, 10 fps")
    print("\n| sequence | capture to command (median, p95) | settled within 10 % at | "
          "largest offset after 3 s |\n| --- | --- | --- | --- |")
    with ServiceProcess(workers=1) as service:
        for name in args.sequences.split(","):
            r = run(service, name, args.preset, args.seconds)
            settled = "never" if math.isnan(r["settled_s"]) else f"{r['settled_s']:.1f} s"
            print(f"| {name} | {r['latency_ms']:.0f} ms, {r['latency_p95_ms']:.0f} ms | "
                  f"{settled} | {r['after_3s']:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

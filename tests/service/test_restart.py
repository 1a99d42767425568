"""A lone instance restarted (SIGTERM, and SIGKILL) with its state file resumes the pilot's
track: the same session, from its last box, status ``resumed``; and meanwhile the MAVLink
camera says ERROR with the reason, never IDLE. Real processes: the service, a station
publishing a real sequence, ``MavlinkCameras`` and a pymavlink ground station."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

pytest.importorskip("zenoh")

from arcf.adapters.mavlink import CameraConfig, MavlinkCameras
from arcf.client import TrackingClient
from arcf.loadtools.groundstation import GroundStation
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.waiting import wait_until
from arcf.schemas import ErrorCode, Result, ResultStatus, SessionSpec, from_json

mav = mavutil.mavlink
pytestmark = [pytest.mark.integration, pytest.mark.heavy]
STREAM, COMP, W, H = "cam1", 100, 1280, 720


def _registered(state: Path) -> list[str]:
    """The session ids the state file holds now."""
    try:
        lines = state.read_text().splitlines()
    except FileNotFoundError:
        return []
    return [spec.session_id for spec in (from_json(x, SessionSpec) for x in lines if x)
            if isinstance(spec, SessionSpec)]


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL], ids=["sigterm", "sigkill"])
def test_a_restarted_instance_resumes_the_pilots_track(tmp_path: Path, wakeboard7: Any,
                                                       how: signal.Signals) -> None:
    state = tmp_path / "sessions.jsonl"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    args = ("--state-file", str(state))
    service = ServiceProcess(*args, listen=endpoint, workers=1)
    data = [p.read_bytes() for p in wakeboard7.frames]
    publisher = TrackingClient(connect=[endpoint])
    watcher = TrackingClient(connect=[endpoint])
    results: list[Result] = []
    watch = watcher.results(STREAM, callback=results.append)
    camera_client = TrackingClient(connect=[endpoint])
    port = free_port()
    camera = MavlinkCameras(camera_client, f"udpin:127.0.0.1:{port}", [CameraConfig(STREAM, COMP)],
                            status_interval_s=0.2).start()
    station = GroundStation(port, COMP)
    stop = threading.Event()

    def publish() -> None:
        for seq in range(1800):  # bounded: 3 minutes at 10 fps
            if stop.wait(0.1):
                return
            publisher.publish_frame(STREAM, data=data[seq % len(data)], seq=seq)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        wait_until(lambda: camera.link_up and camera.cameras[0].last_frame is not None,
                   timeout=60, what="the station heard, frames flowing")
        seq = camera.cameras[0].last_frame.seq
        x, y, w, h = wakeboard7.groundtruth[seq % len(data)]
        result, texts = station.command(mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, (x - 1) / W,
                                        (y - 1) / H, (x - 1 + w) / W, (y - 1 + h) / H)
        assert result == mav.MAV_RESULT_ACCEPTED, texts
        session = camera.cameras[0].session_id
        assert session is not None

        def mine(status: str | None = None) -> list[Result]:
            return [r for r in list(results) if r.session_id == session
                    and (status is None or r.status == status)]

        wait_until(lambda: len(mine("tracking")) >= 10, timeout=60, what="10 tracked frames")
        wait_until(lambda: _registered(state) == [session], timeout=30,
                   what="the session in the state file")

        t_down = time.monotonic()
        if how == signal.SIGTERM:
            assert service.stop() == 0
            # the last word of the stopped instance: interrupted, not ended
            (last,) = mine("stopped")
            assert last.code == ErrorCode.INTERRUPTED, last
        else:
            service.kill()
        assert _registered(state) == [session]  # kept for the restart

        # while the service is away: ERROR, with the reason; never IDLE
        wait_until(lambda: [s for s in station.since(t_down, "CAMERA_TRACKING_IMAGE_STATUS")
                            if s.tracking_status == mav.CAMERA_TRACKING_STATUS_FLAGS_ERROR],
                   timeout=30, what="an ERROR status once the service is gone")
        wait_until(lambda: any("tracking stale" in t for t in
                               (m.text for m in station.since(t_down, "STATUSTEXT"))),
                   timeout=30, what="a STATUSTEXT saying why")
        texts = [m.text for m in station.since(t_down, "STATUSTEXT")]
        if how == signal.SIGTERM:
            assert any("tracking service stopped" in t for t in texts), texts
        else:  # its router went with it: no frame, no result, and that is why
            assert any("no link to the tracking service" in t for t in texts), texts
        seen_down = len(mine())

        # the restarted instance resumes the session as it joins, before its ready line
        service = ServiceProcess(*args, listen=endpoint, workers=1)
        wait_until(lambda: mine("resumed"), timeout=60, what="the session resumed")
        resumed = mine("resumed")
        assert len(resumed) == 1 and resumed[0].frame_seq > mine("tracking")[0].frame_seq
        wait_until(lambda: any(r.status == ResultStatus.TRACKING
                               for r in mine()[seen_down:]), timeout=60,
                   what="tracking after the resume")
        wait_until(lambda: any(s.tracking_status & mav.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
                               for s in station.since(t_down, "CAMERA_TRACKING_IMAGE_STATUS")),
                   timeout=30, what="the camera ACTIVE again")
        assert camera.cameras[0].session_id == session
        statuses = station.since(t_down, "CAMERA_TRACKING_IMAGE_STATUS")
        assert all(s.tracking_status != mav.CAMERA_TRACKING_STATUS_FLAGS_IDLE
                   for s in statuses), [s.tracking_status for s in statuses]
        texts = [m.text for m in station.since(t_down, "STATUSTEXT")]
        assert texts.index("tracking resumed") > min(
            i for i, t in enumerate(texts) if "tracking stale" in t), texts

        # the pilot still holds the session: its stop ends it, and it leaves the state file
        result, texts = station.command(mav.MAV_CMD_CAMERA_STOP_TRACKING)
        assert result == mav.MAV_RESULT_ACCEPTED, texts
        wait_until(lambda: _registered(state) == [], timeout=30,
                   what="the stopped session gone from the state file")
    finally:
        stop.set()
        thread.join(timeout=5)
        station.close()
        camera.close()
        watch.close()
        for client in (camera_client, watcher, publisher):
            client.close()
        service.stop()

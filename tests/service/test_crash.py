"""Crash containment end to end: a real ``arcf-service`` whose worker processes are killed by
real signals while real JPEG frames stream over Zenoh on loopback. A killed worker's session
resumes from its last box, the cause is counted, and a stream on whose frames workers die
twice is quarantined: its sessions end with a ``quarantined`` notice and starts on it are
refused, while another stream starts and runs. (tests/service/test_service.py checks that a
stream on another worker loses no frame when one dies.)"""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

pytest.importorskip("zenoh")

from arcf.client import ServiceError, TrackingClient
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess, worker_pids
from arcf.loadtools.waiting import next_result, wait_until
from arcf.schemas import ErrorMessage, KeySpace, decode
from arcf.service.scrape import by_label, fetch

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

#: frames a second the feeder sends: several times what ARCF-HC follows on one core on any
#: machine (a frame costs it 10 ms or more), so that a frame always waits and the worker is
#: nearly always on one of the stream's frames when it is killed; the service's
#: max_stream_fps is raised above it (``FEED_FPS`` frames would otherwise be refused)
FEED_FPS = 200


def test_a_stream_whose_frames_workers_die_on_twice_is_quarantined() -> None:
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    data = [p.read_bytes() for p in seq.frames[:20]]
    keys = KeySpace()
    svc = ServiceProcess("--quarantine-after", "2", "--quarantine-s", "600",
                         "--max-stream-fps", str(2 * FEED_FPS), workers=1)
    stop = threading.Event()
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            results = client.results("hot")
            notices: list[ErrorMessage] = []
            sub = client.session.declare_subscriber(
                keys.errors("hot"),
                lambda s: notices.append(decode(s.payload.to_bytes(), expected=ErrorMessage)))
            client.start("hot", seq.init_box, preset="arcf-hc", frame_seq=0)

            def feed() -> None:  # bounded in frames and time
                t_end = time.monotonic() + 600
                for i in range(30_000):
                    if stop.is_set() or time.monotonic() > t_end:
                        return
                    client.publish_frame("hot", data=data[i % len(data)], seq=i)
                    if stop.wait(1 / FEED_FPS):  # the feed's pace; ends at once when told
                        return

            feeder = threading.Thread(target=feed, name="feeder", daemon=True)
            feeder.start()

            def strikes() -> float:
                return svc.metric("arcf_stream_crash_strikes_total")

            last, kills, statuses = -1, 0, []
            # a death between two frames strikes nobody: kill until two struck (bounded)
            while strikes() < 2 and kills < 8:
                r = next_result(results, last, timeout=180)  # running (again)
                statuses.append(r.status)
                last = r.frame_seq
                for _ in range(3):  # a few frames in: the worker is busy with them
                    last = next_result(results, last, timeout=60).frame_seq
                (pid,) = worker_pids(svc.proc.pid)
                os.kill(pid, signal.SIGSEGV)
                kills += 1
                wait_until(lambda k=kills: svc.metric("arcf_worker_deaths_total") == k,
                           timeout=60, what=f"death {kills} counted")
            assert strikes() == 2, f"only {strikes():.0f} of {kills} deaths on a frame"
            assert "resumed" in statuses  # after the first strike it came back
            deaths = by_label(fetch(svc.metrics_url), "arcf_worker_deaths_total", "cause")
            assert deaths == {"SIGSEGV": kills}
            assert svc.metric("arcf_streams_quarantined_total") == 1
            wait_until(lambda: any(n.code == "quarantined" for n in notices), timeout=30,
                       what="the quarantined notice on the stream's error key")
            with pytest.raises(ServiceError) as refused:
                client.start("hot", seq.init_box, preset="arcf-hc")
            assert refused.value.code == "quarantined"
            assert "quarantined for" in str(refused.value)
            stop.set()
            feeder.join(timeout=30)
            # nothing of the stream runs any more; another stream starts and is tracked
            assert not any(s.stream_id == "hot" for s in client.status().sessions)

            def cool_started() -> bool:
                try:
                    client.start("cool", seq.init_box, preset="bacf", frame_seq=0, timeout=10)
                    return True
                except (ServiceError, TimeoutError):  # the replacement may still start
                    return False

            wait_until(cool_started, timeout=180, what="a start on another stream")
            cool = client.results("cool")
            client.publish_frame("cool", data=data[0], seq=0)
            assert next_result(cool, -1, timeout=60).frame_seq == 0
            sub.undeclare()
        control = by_label(fetch(svc.metrics_url), "arcf_control_requests_total", "outcome")
        assert control.get("quarantined") == 1  # the refused start, counted
    finally:
        stop.set()
        assert svc.stop() == 0

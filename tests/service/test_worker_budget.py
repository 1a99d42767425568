"""A worker's time is shared: neighbours that take more than the worker has (heavy tracking,
a stream that is expensive to decode) are shed, costliest first, with a counted reason, and a
light stream on the same worker keeps running. Video units are bounded before they reach the
decoder (pictures above ``max_pixels``). A real service with one worker, real frames."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

pytest.importorskip("zenoh")

from arcf.client import TrackingClient
from arcf.data import data_root
from arcf.loadtools.driver import Clip
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.video import encode_video
from arcf.loadtools.waiting import wait_until
from arcf.schemas import ErrorMessage, KeySpace, decode
from arcf.service.scrape import by_label, fetch

pytestmark = [pytest.mark.integration, pytest.mark.heavy,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

KEYS = KeySpace()


class Station:
    """Publishes a stream's frames at ``fps`` in a thread (bounded in count and time) and
    records every result of the stream."""

    def __init__(self, client: TrackingClient, stream: str, frames: list[bytes], fps: float,
                 encoding: str = "jpeg", loop_from: int = 0) -> None:
        self.client, self.stream, self.frames = client, stream, frames
        self.fps, self.encoding, self.loop_from = fps, encoding, loop_from
        self.results: list[Any] = []
        self.sub = client.results(stream, callback=self.results.append)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _frame(self, k: int) -> bytes:
        if k < len(self.frames):
            return self.frames[k]
        span = len(self.frames) - self.loop_from
        return self.frames[self.loop_from + (k - self.loop_from) % span]

    def _run(self) -> None:
        t0 = time.monotonic()
        for k in range(int(120 * self.fps)):  # two minutes at most
            if self.stop.is_set():
                return
            self.client.publish_frame(self.stream, data=self._frame(k), seq=k,
                                      encoding=self.encoding)
            self.stop.wait(max(0.0, t0 + (k + 1) / self.fps - time.monotonic()))

    def stopped(self) -> list[Any]:
        return [r for r in list(self.results) if r.status.value == "stopped"]

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5)
        self.sub.close()


def shed(svc: ServiceProcess) -> dict[str, float]:
    assert svc.metrics_url is not None
    return by_label(fetch(svc.metrics_url), "arcf_sessions_shed_total", "cause")


def test_heavy_neighbours_are_shed_costliest_first_and_a_light_stream_keeps_running(
        clip: Clip) -> None:
    """Twelve ARCF-HC sessions on one stream at 10 fps ask the single worker for more than a
    core; a BACF stream beside them starves (its frames wait or are dropped). The worker ends
    the costliest sessions, one per two seconds, each saying why, until the victim is served;
    the victim's session is never touched."""
    svc = ServiceProcess("--workers", "1")
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            victim = Station(client, "victim", clip.frames, fps=10)
            heavy = Station(client, "heavy", clip.frames, fps=10)
            victim_id = client.start("victim", clip.box, preset="bacf").session_id
            heavy_ids = {client.start("heavy", clip.box, preset="arcf-hc").session_id
                         for _ in range(12)}
            victim.thread.start()
            heavy.thread.start()
            try:
                wait_until(lambda: heavy.stopped(), 60, "a heavy session shed")
            finally:
                heavy.close()
                victim.close()
            first = heavy.stopped()[0]
            assert first.session_id in heavy_ids and first.code.value == "limit_exceeded"
            assert "worker_budget" in first.message and "tracking took" in first.message
            assert victim.stopped() == []
            assert shed(svc).get("tracking", 0) >= 1 and shed(svc).get("decoding", 0) == 0
            running = {s.session_id for s in client.status().sessions}
            assert victim_id in running
    finally:
        assert svc.stop() == 0


def black_stream(width: int, height: int) -> list[bytes]:
    """A keyframe and two P-units of a black picture: what a camera sends of a still scene,
    tiny on the wire (the P-units are a few bytes) and costly to decode when large."""
    image = np.zeros((height, width, 3), np.uint8)
    return encode_video([image] * 3, "h264", fps=30, gop=1000)


def test_a_stream_too_large_to_decode_is_refused_by_default_and_shed_when_allowed(
        clip: Clip) -> None:
    """A 6000 x 6000 H.264 stream (36 MP of skip units at 30/s, about 90 ms each to decode
    and convert): refused at its parameter set under the default max_pixels (4K), counted as
    oversized. With max_pixels raised to admit it, two such streams starve a JPEG stream on
    the same worker, and the costlier one's sessions are shed for its decoding."""
    units = black_stream(6000, 6000)
    box = [100.0, 100.0, 60.0, 60.0]
    svc = ServiceProcess("--workers", "1")
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            notices: list[ErrorMessage] = []
            sub = client.session.declare_subscriber(KEYS.errors("big"), lambda s: notices.append(
                decode(s.payload.to_bytes(), expected=ErrorMessage)))
            client.start("big", box, preset="bacf")
            for k in range(5):
                client.publish_frame("big", data=units[min(k, 2)], seq=k, encoding="h264")
            wait_until(lambda: any("max_pixels" in n.message for n in notices), 30,
                       "the oversized stream reported")
            sub.undeclare()
            assert any("6016x6000" in n.message or "6000x6000" in n.message for n in notices)
            assert svc.metrics_url is not None
            resyncs = by_label(fetch(svc.metrics_url), "arcf_video_resyncs_total", "cause")
            assert resyncs.get("oversized", 0) >= 1
    finally:
        assert svc.stop() == 0

    # admitted, each unit costs ~60 ms to decode: two such streams at 30 units/s (a keyframe
    # every 30, as a camera sends) ask for more than three cores
    svc = ServiceProcess("--workers", "1", "--max-pixels", "40000000")
    gop = [units[0]] + [units[2]] * 29
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            victim = Station(client, "victim", clip.frames, fps=10)
            bigs = [Station(client, f"big{k}", gop, fps=30, encoding="h264") for k in (1, 2)]
            victim_id = client.start("victim", clip.box, preset="bacf").session_id
            for k in (1, 2):
                client.start(f"big{k}", box, preset="bacf")
            for station in (victim, *bigs):
                station.thread.start()
            try:
                wait_until(lambda: any(b.stopped() for b in bigs), 60,
                           "an expensive stream shed")
            finally:
                for station in (*bigs, victim):
                    station.close()
            ended = next(b.stopped()[0] for b in bigs if b.stopped())
            assert ended.code.value == "limit_exceeded"
            assert f"decoding stream '{ended.stream_id}'" in ended.message
            assert victim.stopped() == []
            assert shed(svc).get("decoding", 0) >= 1
            assert victim_id in {s.session_id for s in client.status().sessions}
    finally:
        assert svc.stop() == 0


def test_a_worker_over_its_memory_bound_resets_its_decoders_and_streams_resume(
        clip: Clip) -> None:
    """With worker_max_rss_mb below what any worker uses, every second the worker drops its
    video decoders (told and counted, cause 'memory'); the stream resumes at its next
    keyframe each time, so results keep coming."""
    from arcf.client.media.images import decode_compressed

    images = [decode_compressed(f) for f in clip.frames[:30]]
    units = encode_video(images, "h264", fps=30, gop=10)
    svc = ServiceProcess("--workers", "1", "--worker-max-rss-mb", "1")
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            notices: list[ErrorMessage] = []
            sub = client.session.declare_subscriber(KEYS.errors("cam"), lambda s: notices.append(
                decode(s.payload.to_bytes(), expected=ErrorMessage)))
            cam = Station(client, "cam", units, fps=30, encoding="h264")
            client.start("cam", clip.box, preset="bacf")
            cam.thread.start()
            try:
                wait_until(lambda: any("worker_max_rss_mb" in n.message for n in notices), 30,
                           "a decoder reset told")
                reset_at = max(r.frame_seq for r in list(cam.results)) if cam.results else 0
                wait_until(lambda: any(r.status.value == "tracking" and r.frame_seq > reset_at
                                       for r in list(cam.results)), 30,
                           "tracking again after a reset")
            finally:
                cam.close()
                sub.undeclare()
            assert svc.metrics_url is not None
            resyncs = by_label(fetch(svc.metrics_url), "arcf_video_resyncs_total", "cause")
            assert resyncs.get("memory", 0) >= 1
    finally:
        assert svc.stop() == 0

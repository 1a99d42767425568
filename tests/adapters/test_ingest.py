"""Camera in: real senders on loopback (FFmpeg's muxers through PyAV, GStreamer's RTSP server),
``arcf-ingest`` in between, a real service behind it.

Checked: H.264 passes through unchanged (the service's stream decodes to the very pictures
the camera encoded, bit for bit) from an MP4 file, RTP/UDP without an SDP (QGroundControl's
convention), MPEG-TS/UDP and RTSP; capture times follow the source's clock; the picture size
is declared; a sender that restarts and datagrams lost on the way leave counted holes in the
numbering, the service resynchronises at the next keyframe and tracking goes on; a source
that never comes, a file that cannot be read and a service that is not up yet are waited for
or refused with a reason, never a traceback.
"""

from __future__ import annotations

import itertools
import subprocess
import sys
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import cast

import numpy as np
import pytest

pytest.importorskip("zenoh")

from arcf.adapters import ingest as ingest_module
from arcf.adapters.ingest import CaptureClock, Ingest, parse_source, rtp_sdp
from arcf.client import TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.senders import (
    RtspServer,
    UdpRelay,
    VideoSender,
    free_rtp_port,
    rtsp_server_problem,
    write_video_file,
)
from arcf.loadtools.video import decode_video, encode_video
from arcf.loadtools.waiting import wait_until
from arcf.schemas import Frame, Result

N, GOP, FPS = 30, 10, 30


# ---------------------------------------------------------------------------- pure parts
@pytest.mark.parametrize("source, read", [("rtp://127.0.0.1:5600", 3), ("flight.mp4", 4)])
def test_a_silent_live_source_ends_its_reading_after_one_timeout(monkeypatch, source: str,
                                                                 read: int) -> None:
    """FFmpeg's parser holds a live H.264 source's last unit: the read PyAV's timeout stops
    hands that unit out instead of failing, and the next read would wait a whole timeout
    more. The reading ends after the unit of a read that took the whole timeout; a file's
    slow read is only slow."""
    clock = [0.0]
    monkeypatch.setattr(ingest_module, "time", SimpleNamespace(monotonic=lambda: clock[0]))

    def demux(_stream: object):
        for took in (0.03, 0.03, 3.0, 0.03):  # the third read is the one the timeout stops
            clock[0] += took
            yield SimpleNamespace(size=100, is_keyframe=False, is_corrupt=False)

    ingest = Ingest(cast(TrackingClient, None), parse_source(source), "cam", read_timeout_s=3.0)
    packets = list(ingest._packets(SimpleNamespace(demux=demux), None, 0))
    assert len(packets) == read  # the stopped read's unit is handed out, none after it
    assert ingest.counts["read_timeouts"] == 4 - read


def test_sources_from_what_an_operator_types() -> None:
    rtsp = parse_source("rtsp://10.0.0.2:8554/main")
    assert (rtsp.kind, rtsp.options["rtsp_transport"], rtsp.live) == ("rtsp", "tcp", True)
    assert parse_source("rtsp://h/x", rtsp_transport="udp").options["rtsp_transport"] == "udp"
    qgc = parse_source("rtp://:5600")
    assert (qgc.kind, qgc.format) == ("rtp", "sdp")
    assert qgc.sdp is not None and "m=video 5600 RTP/AVP 96" in qgc.sdp
    assert "a=rtpmap:96 H264/90000" in qgc.sdp and "c=IN IP4 0.0.0.0" in qgc.sdp
    assert "H265/90000" in (parse_source("rtp://@127.0.0.1:5602", rtp_codec="h265").sdp or "")
    # an address keeps a UDP source to that link; without one it listens everywhere (said)
    assert qgc.everywhere and parse_source("udp://:5601").everywhere
    assert parse_source("udp://0.0.0.0:5601").everywhere
    assert not any(parse_source(t).everywhere for t in (
        "rtp://127.0.0.1:5600", "rtp://@10.0.0.1:5600", "udp://192.168.1.2:5601",
        "rtsp://h/x", "flight.mp4"))
    assert parse_source("cam.sdp").kind == "rtp"
    ts = parse_source("udp://:5601")
    assert ts.kind == "mpegts" and "overrun_nonfatal=1" in ts.url
    assert parse_source("/dev/video0").kind == parse_source("v4l2:/dev/video2").kind == "v4l2"
    clip = parse_source("flight.mp4")
    assert (clip.kind, clip.live) == ("file", False)
    for bad in ("rtp://host", "rtp://:0", "rtp://:99999"):
        with pytest.raises(ValueError):
            parse_source(bad)
    with pytest.raises(ValueError, match="dynamic"):
        rtp_sdp("0.0.0.0", 5600, payload_type=33)
    with pytest.raises(ValueError, match="codec"):
        rtp_sdp("0.0.0.0", 5600, codec="vp8")


def test_capture_clock_follows_the_source_and_relays_on_a_jump() -> None:
    clock = CaptureClock(slack_s=1.0)
    t0 = 1_700_000_000_000_000_000
    assert clock.stamp(10.0, t0) == t0
    # jitter on arrival does not move the stamps: the source's clock does
    assert clock.stamp(10.5, t0 + 700_000_000) == t0 + 500_000_000
    assert clock.stamp(None, t0 + 123) == t0 + 123  # no presentation time: arrival
    # a restarted sender's clock starts again: laid anew on the wall clock
    assert clock.stamp(0.0, t0 + 2_000_000_000) == t0 + 2_000_000_000
    assert clock.relaid == 1


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def camera(wakeboard7):
    """The first N pictures of wakeboard7 encoded as a camera streams them (keyframes every
    GOP, parameter sets in front of each), and what a decoder makes of them."""
    images = [decode_compressed(p.read_bytes()) for p in wakeboard7.frames[:N]]
    units = encode_video(images, "h264", fps=FPS, gop=GOP, repeat_headers=True)
    assert len(units) == N
    size = (images[0].shape[1], images[0].shape[0])
    return wakeboard7, units, decode_video(units, "h264"), size


@pytest.fixture(scope="module")
def service():
    svc = ServiceProcess(workers=1)
    yield svc
    svc.stop()


class Watch:
    """A station listening to the stream's frames (what the ingest published)."""

    def __init__(self, client: TrackingClient, stream: str) -> None:
        self.frames: list[Frame] = []
        self._lock = threading.Lock()
        self._sub = client.frames(stream, callback=self._add)

    def _add(self, frame: Frame) -> None:
        with self._lock:
            self.frames.append(frame)

    def snapshot(self) -> list[Frame]:
        with self._lock:
            return sorted(self.frames, key=lambda f: f.seq)

    def close(self) -> None:
        self._sub.close()


def chains(frames: list[Frame]) -> list[list[Frame]]:
    """Runs of consecutive numbers: a hole starts a new chain."""
    out: list[list[Frame]] = []
    for f in frames:
        if out and f.seq == out[-1][-1].seq + 1:
            out[-1].append(f)
        else:
            out.append([f])
    return out


def assert_passed_through(frames: list[Frame], pictures: list[np.ndarray],
                          size: tuple[int, int]) -> int:
    """Each chain starts at a keyframe and decodes, with a fresh decoder, to pictures the
    camera encoded, bit for bit and in order: nothing was re-encoded. Returns how many."""
    assert frames, "nothing published"
    assert all(f.encoding.value == "h264" and (f.width, f.height) == size for f in frames)
    decoded = 0
    for chain in chains(frames):
        got = decode_video([f.payload for f in chain], "h264")
        assert len(got) == len(chain)
        k = -1
        for picture in got:
            matches = [i for i in range(k + 1, len(pictures))
                       if np.array_equal(picture, pictures[i])]
            assert matches, "a published unit decodes to a picture the camera never sent"
            k = matches[0]
        decoded += len(got)
    return decoded


# ---------------------------------------------------------------------------- sources
def test_mp4_file_passes_through_with_its_clock_and_size(camera, service, tmp_path) -> None:
    _, units, pictures, size = camera
    mp4 = write_video_file(units, tmp_path / "flight.mp4", size)  # length-prefixed units
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        watch = Watch(client, "file-cam")
        ingest = Ingest(client, parse_source(str(mp4)), "file-cam", realtime=False).start()
        wait_until(lambda: ingest.done, timeout=60, what="the file played")
        wait_until(lambda: len(watch.snapshot()) == N, timeout=30, what="every unit seen")
        frames = watch.snapshot()
        watch.close()
        ingest.close()
    assert [f.seq for f in frames] == list(range(N))
    assert ingest.counts["published"] == N and ingest.counts["keyframes"] == N // GOP
    assert assert_passed_through(frames, pictures, size) == N
    steps = np.diff([f.capture_ts_ns for f in frames])
    assert np.all(np.abs(steps - 1e9 / FPS) <= 1e6)  # the file's clock: 1/30 s a picture


def _ingest_and_check(service, source: str, sender_factory, camera, stream: str) -> Ingest:
    pictures, size = camera[2], camera[3]
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        watch = Watch(client, stream)
        ingest = Ingest(client, parse_source(source), stream).start()
        sender = sender_factory()
        try:
            wait_until(lambda: sender.done, timeout=60, what="the sender sent everything")
            assert sender.error is None, sender.error
            # the last units may wait in the receiver until the source goes quiet
            wait_until(lambda: ingest.counts["read_timeouts"] >= 1, timeout=30,
                       what="the source went quiet")
            ingest.close()
            # frames reach the station after the ingest counted them published
            wait_until(lambda: len(watch.snapshot()) >= ingest.counts["published"],
                       timeout=30, what="every published frame seen")
            frames = watch.snapshot()
        finally:
            ingest.close()
            watch.close()
    assert ingest.counts["published"] == len(frames)
    # loopback may lose a datagram on a starved machine: then a hole, counted, and the
    # chain starts again at a keyframe
    holes = sum(b.seq - a.seq - 1 for a, b in itertools.pairwise(frames))
    assert holes == ingest.counts["gaps"]
    assert assert_passed_through(frames, pictures, size) >= GOP
    return ingest


def test_rtp_without_sdp_on_the_port_convention(camera, service) -> None:
    _, units, _, size = camera
    port = free_rtp_port()
    ingest = _ingest_and_check(
        service, f"rtp://127.0.0.1:{port}",
        lambda: VideoSender(units, f"rtp://127.0.0.1:{port}", "rtp", size).start(),
        camera, "rtp-cam")
    assert ingest.counts["open_failed"] == 0


def test_mpegts_over_udp(camera, service) -> None:
    _, units, _, size = camera
    port = free_port()
    _ingest_and_check(
        service, f"udp://127.0.0.1:{port}",
        lambda: VideoSender(units, f"udp://127.0.0.1:{port}?pkt_size=1316", "mpegts",
                            size).start(),
        camera, "ts-cam")


def test_rtsp_from_gstreamers_server(camera, service, tmp_path) -> None:
    problem = rtsp_server_problem()
    if problem is not None:
        pytest.skip(problem)
    _, units, pictures, size = camera
    ts = write_video_file(units, tmp_path / "cam.ts", size)
    with RtspServer(ts, free_port()) as server, \
            TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        watch = Watch(client, "rtsp-cam")
        ingest = Ingest(client, parse_source(server.url), "rtsp-cam",
                        read_timeout_s=2.0).start()
        try:
            # the file ends, the server ends the session: the ingest opens it again and the
            # camera's pictures come a second time, after a hole in the numbering
            wait_until(lambda: ingest.counts["opened"] >= 2 and ingest.counts["published"]
                       >= N + GOP, timeout=120, what="the RTSP stream played twice")
            ingest.close()
            # frames reach the station after the ingest counted them published
            wait_until(lambda: len(watch.snapshot()) >= ingest.counts["published"],
                       timeout=30, what="every published frame seen")
        finally:
            ingest.close()
            frames = watch.snapshot()
            watch.close()
    assert len(chains(frames)) >= 2 and ingest.counts["gaps"] >= 1
    assert assert_passed_through(frames, pictures, size) >= N + GOP


# ---------------------------------------------------------------------------- failures
def _results(client: TrackingClient, stream: str) -> tuple[list[Result], threading.Lock]:
    got: list[Result] = []
    lock = threading.Lock()

    def add(r: Result) -> None:
        with lock:
            got.append(r)

    client.results(stream, callback=add)
    return got, lock


def test_sender_restart_and_lost_datagrams_resynchronise(camera, service) -> None:
    """RTP through a relay that loses a burst in the first GOP's second half; the sender
    then stops and a new one (a rebooted camera) starts. Every hole is counted by the
    ingest, the service resynchronises at a keyframe each time, and a session on the stream
    tracks on until the end: results keep coming, the last ones tracking."""
    seq, units, _, size = camera
    port = free_rtp_port()
    # 20 datagrams lost half-way through the first sender's second pass over the clip (well
    # after the receiver's probing): an IDR is about 170 datagrams, a P-frame 30
    per_pass = sum(-(-len(u) // 1400) for u in units)
    burst = range(per_pass * 3 // 2, per_pass * 3 // 2 + 20)
    relay = UdpRelay(port, lambda i: i in burst)
    resyncs0 = service.metric("arcf_video_resyncs_total")
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        got, lock = _results(client, "lossy-cam")
        ingest = Ingest(client, parse_source(f"rtp://127.0.0.1:{port}"), "lossy-cam",
                        read_timeout_s=1.0).start()
        try:
            first = VideoSender(units, f"rtp://127.0.0.1:{relay.port}", "rtp", size,
                                repeat=3).start()
            wait_until(lambda: ingest.counts["published"] >= 1, timeout=30,
                       what="the first unit published")
            client.start("lossy-cam", seq.init_box, preset="bacf")
            wait_until(lambda: first.done, timeout=60, what="the first sender done")
            assert relay.lost == len(burst)
            wait_until(lambda: ingest.counts["read_timeouts"] >= 1, timeout=30,
                       what="the silence after the first sender noticed")
            before = ingest.counts["published"]
            second = VideoSender(units, f"rtp://127.0.0.1:{relay.port}", "rtp", size).start()
            wait_until(lambda: second.done, timeout=60, what="the second sender done")
            wait_until(lambda: ingest.counts["read_timeouts"] >= 2, timeout=30,
                       what="the silence after the second sender noticed")
            assert ingest.counts["published"] >= before + GOP  # the restarted camera's
            last = ingest.counts["published"] - 1 + ingest.counts["gaps"]
            wait_until(lambda: any(r.frame_seq == last and r.status.value != "stale"
                                   for r in list(got)), timeout=30,
                       what="the last unit answered")
        finally:
            ingest.close()
            relay.close()
    with lock:
        results = list(got)
    # the loss and the restart each left a hole (more if the machine lost datagrams too)
    assert ingest.counts["gaps"] >= 2 and ingest.counts["reopened"] >= 1
    assert ingest.counts["lost_rtp"] >= len(burst)  # FFmpeg's report, counted
    assert service.metric("arcf_video_resyncs_total") - resyncs0 >= 1
    answers = [r for r in results if r.status.value != "stale"]  # the silence's notices aside
    assert answers[-1].frame_seq == last and answers[-1].status.value == "tracking"
    assert [r.frame_seq for r in results] == sorted(r.frame_seq for r in results)


def test_a_source_that_never_comes_is_waited_for_not_fatal(service) -> None:
    with TrackingClient(connect=[service.endpoint]) as client:
        ingest = Ingest(client, parse_source(f"rtp://127.0.0.1:{free_rtp_port()}"), "quiet",
                        open_timeout_s=0.5, read_timeout_s=0.5, retry_s=0.1,
                        retry_max_s=0.2).start()
        wait_until(lambda: ingest.counts["reopened"] >= 3, timeout=60,
                   what="three attempts to open the silent source")
        assert ingest.alive and ingest.counts["published"] == 0
        ingest.close()
    assert not ingest.alive


def test_a_file_that_cannot_be_read_ends_with_its_reason(service, tmp_path) -> None:
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00" * 1000)
    with TrackingClient(connect=[service.endpoint]) as client:
        ingest = Ingest(client, parse_source(str(junk)), "junk").start()
        wait_until(lambda: ingest.done, timeout=30, what="the junk file given up")
        assert ingest.counts["open_failed"] == 1 and ingest.counts["published"] == 0
        ingest.close()


# ---------------------------------------------------------------------------- the command
def test_a_restarted_ingest_numbers_on_under_a_running_session(camera, service,
                                                                tmp_path) -> None:
    """An ingest stopped and started again (a restarted arcf-ingest) while a session tracks
    its stream numbers on from the stream's last tracked frame: no frame of the second run
    is refused as a jump, its numbers follow the first run's, the session goes on."""
    seq, units, _, size = camera
    mp4 = write_video_file(units, tmp_path / "camera.mp4", size)
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        got, lock = _results(client, "again")
        refused: list[str] = []
        client.errors("again", callback=lambda e: refused.append(e.code.value))
        first = Ingest(client, parse_source(str(mp4)), "again").start()
        wait_until(lambda: first.counts["published"] >= 1, timeout=30, what="a first unit")
        client.start("again", seq.init_box, preset="bacf")
        wait_until(lambda: first.done, timeout=60, what="the first run played")
        first.close()

        def tracked() -> list[int]:
            with lock:
                return [r.frame_seq for r in got if r.track_state is not None]

        wait_until(lambda: tracked(), timeout=30, what="tracked frames")
        last = max(tracked())
        second = Ingest(client, parse_source(str(mp4)), "again").start()
        wait_until(lambda: second.done, timeout=60, what="the second run played")
        second.close()
        wait_until(lambda: any(k > last for k in tracked()), timeout=30,
                   what="the session tracking the second run")
    # numbered on, not from 0 (its numbers would all be at or below ``last``: the wait above
    # would fail), by a jump the service takes at once; a worker that lagged by more than
    # RESUME_MARGIN units of video refuses a few as out of order and follows at the third
    assert "sequence_jump" not in refused, refused
    assert refused.count("stale_frame") <= 1, refused


def test_command_waits_for_a_service_that_starts_later(camera, tmp_path,
                                                       started_before_the_service) -> None:
    """``arcf-ingest`` started before the service: it says what it waits for, then plays
    the file once the service answers; with nothing to wait for, exit 2 and a reason."""
    _, units, _, size = camera
    mp4 = write_video_file(units, tmp_path / "flight.mp4", size)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = [sys.executable, "-m", "arcf.adapters.ingest", str(mp4), "--stream", "late",
           "--as-fast-as-possible", "-e", endpoint]
    with started_before_the_service([*cmd, "--wait-s", "120"], endpoint) as early:
        assert early.proc.wait(timeout=120) == 0
    text = "".join(early.lines)
    assert "Traceback" not in text and "no Zenoh router at" in text
    assert f"'published': {N}" in text

    gone = subprocess.run([*cmd, "--wait-s", "1"], capture_output=True, text=True,
                          timeout=60)
    assert gone.returncode == 2 and "Traceback" not in gone.stderr
    assert "did not answer" in gone.stderr and "giving up" in gone.stderr


def test_command_refuses_a_bad_source(tmp_path: Path) -> None:
    bad = subprocess.run([sys.executable, "-m", "arcf.adapters.ingest", "rtp://nowhere",
                          "--stream", "x"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "rtp://[HOST]:PORT" in bad.stderr

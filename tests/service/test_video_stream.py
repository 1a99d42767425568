"""H.264 / H.265 streams through a real service: a shared sequence encoded with libx264
(PyAV's wheels), sent as the service's own frames (``encoding: h264``) and as CDR
``foxglove.CompressedVideo`` on ``video/<stream>/stream``, gives the library's boxes on the
decoded frames; a lost or damaged access unit resynchronises at the next keyframe, reported
and counted, and tracking resumes there."""

from __future__ import annotations

import queue
import time

import numpy as np
import pytest

pytest.importorskip("zenoh")

import arcf
from arcf.client import TrackingClient
from arcf.client.foxglove import compressed_video
from arcf.client.media.images import decode_compressed
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.video import decode_video, encode_video
from arcf.loadtools.waiting import wait_until
from arcf.schemas import ErrorMessage, KeySpace, decode

pytestmark = pytest.mark.integration
GOP = 10
N = 30
PRESET = "bacf"


@pytest.fixture(scope="module")
def clip(wakeboard7):
    seq = wakeboard7
    images = [decode_compressed(p.read_bytes()) for p in seq.frames[:N]]
    units = encode_video(images, "h264", fps=30, gop=GOP)
    assert len(units) == N
    return seq, units, decode_video(units, "h264")


@pytest.fixture(scope="module")
def hevc_clip(wakeboard7):
    """The first 12 frames as H.265 (libx265), keyframes every 5."""
    images = [decode_compressed(p.read_bytes()) for p in wakeboard7.frames[:12]]
    units = encode_video(images, "h265", fps=30, gop=5)
    assert len(units) == 12
    return wakeboard7, units, decode_video(units, "h265")


@pytest.fixture(scope="module")
def service():
    svc = ServiceProcess(workers=1)
    yield svc
    svc.stop()


def library(pictures: list[np.ndarray], box) -> list:
    return arcf.run_sequence(arcf.create_tracker(PRESET), pictures, box).results


def lockstep(client: TrackingClient, stream: str, units: dict[int, bytes], send,
             box) -> dict[int, object]:
    """Start a session, send each unit once the result of the one before is in (so every
    picture is tracked, whatever the machine's speed), return the results by frame number."""
    results = client.results(stream)
    client.start(stream, box, preset=PRESET, frame_seq=0)
    got: dict[int, object] = {}
    for seq, unit in units.items():
        send(seq, unit)
        deadline = time.monotonic() + 30
        while seq not in got and time.monotonic() < deadline:
            try:
                r = results.get(timeout=1.0)
            except queue.Empty:
                continue
            if r.status != "stale":  # a notice about no frame (a stall over a second)
                got[r.frame_seq] = r
        assert seq in got, f"no result for unit {seq}"
    return got


def test_h264_frames_give_the_librarys_boxes_on_the_decoded_pictures(service, clip) -> None:
    seq, units, pictures = clip
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        got = lockstep(client, "h264-own", dict(enumerate(units)),
                       lambda i, u: client.publish_frame("h264-own", data=u, encoding="h264",
                                                         seq=i), seq.init_box)
    want = library(pictures, seq.init_box)
    assert [got[i].status for i in range(N)] == ["initialized"] + ["tracking"] * (N - 1)
    np.testing.assert_allclose([got[i].box for i in range(N)], [r.box for r in want],
                               atol=1e-9)
    assert [got[i].track_state for i in range(N)] == [r.state.value for r in want]
    assert all(got[i].decode_s > 0 and got[i].dropped == 0 for i in range(N))


def test_a_box_drawn_between_keyframes_lands_on_its_picture(service, clip) -> None:
    """The pilot drew on frame 13 of a stream nobody tracked yet (keyframes at 10 and 20): the
    worker that subscribes when the session starts gets the station's recent units first
    (the SDK keeps them), decodes from keyframe 10, applies the box to frame 13, tracks 14
    to 16 to catch up, and goes on live: the library's boxes started on frame 13."""
    seq, units, pictures = clip
    drawn, sent = 13, 17
    box = tuple(float(v) for v in seq.groundtruth[drawn])
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        for i in range(sent):  # before any session: nobody receives them but the cache
            client.publish_frame("h264-drawn", data=units[i], encoding="h264", seq=i)
        results = client.results("h264-drawn")
        client.start("h264-drawn", box, preset=PRESET, frame_seq=drawn)
        got: list = []

        def through(last: int) -> bool:
            got.extend(r for r in results.iter(timeout=0.2) if r.status != "stale")
            return bool(got) and got[-1].frame_seq >= last

        wait_until(lambda: through(sent - 1), timeout=60, what="the results up to live")
        for i in range(sent, N):  # live, each unit once the one before is tracked
            client.publish_frame("h264-drawn", data=units[i], encoding="h264", seq=i)
            wait_until(lambda i=i: through(i), timeout=60, what=f"the result of frame {i}")
        results.close()
    assert [r.frame_seq for r in got] == list(range(drawn, N))
    assert [r.status for r in got] == ["initialized"] + ["tracking"] * (N - drawn - 1)
    assert got[0].message is None  # on its own picture, not "applied to frame ..."
    want = library(pictures[drawn:], box)
    np.testing.assert_allclose([r.box for r in got], [r.box for r in want], atol=1e-9)
    assert service.metric("arcf_video_replayed_pictures_total") >= 1


@pytest.mark.parametrize("convention", ["frame", "compressed_video"])
def test_h265_in_both_conventions_gives_the_librarys_boxes(service, hevc_clip,
                                                           convention: str) -> None:
    seq, units, pictures = hevc_clip
    stream = f"hevc-{convention.replace('_', '-')}"
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        import zenoh

        pub = client.session.declare_publisher(f"video/{stream}/stream",
                                               congestion_control=zenoh.CongestionControl.BLOCK)

        def send(i: int, unit: bytes) -> None:
            if convention == "frame":
                client.publish_frame(stream, data=unit, encoding="h265", seq=i)
            else:
                pub.put(compressed_video(unit, "h265", 1 + i))

        got = lockstep(client, stream, dict(enumerate(units)), send, seq.init_box)
    want = library(pictures, seq.init_box)
    assert [got[i].status for i in range(len(units))] == (
        ["initialized"] + ["tracking"] * (len(units) - 1))
    np.testing.assert_allclose([got[i].box for i in range(len(units))],
                               [r.box for r in want], atol=1e-9)


def test_compressed_video_on_the_camera_managers_key_gives_the_same_boxes(service,
                                                                          clip) -> None:
    seq, units, pictures = clip
    t0 = 1_700_000_000_000_000_000
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        import zenoh

        pub = client.session.declare_publisher("video/fox/stream",
                                               congestion_control=zenoh.CongestionControl.BLOCK)
        got = lockstep(client, "fox", dict(enumerate(units)),
                       lambda i, u: pub.put(compressed_video(u, "h264", t0 + i * 33_333_333,
                                                             "camera")), seq.init_box)
    want = library(pictures, seq.init_box)
    # numbered by the service in arrival order, stamped with the message's own timestamp
    assert [got[i].capture_ts_ns for i in range(N)] == [t0 + i * 33_333_333 for i in range(N)]
    np.testing.assert_allclose([got[i].box for i in range(N)], [r.box for r in want],
                               atol=1e-9)


@pytest.mark.parametrize("fault", ["lost", "damaged"])
def test_a_lost_or_damaged_unit_resynchronises_at_the_next_keyframe(service, clip,
                                                                   fault: str) -> None:
    seq, units, pictures = clip
    bad = 13
    sent = dict(enumerate(units))
    if fault == "lost":
        del sent[bad]
    else:
        broken = bytearray(units[bad])
        broken[len(broken) // 2:len(broken) // 2 + 40] = bytes(40)
        sent[bad] = bytes(broken)
    stream = f"h264-{fault}"
    keys = KeySpace()
    resyncs = service.metric("arcf_video_resyncs_total")
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        notices: list[ErrorMessage] = []
        sub = client.session.declare_subscriber(
            keys.errors(stream), lambda s: notices.append(decode(s.payload.to_bytes())))
        got = lockstep(client, stream, sent,
                       lambda i, u: client.publish_frame(stream, data=u, encoding="h264", seq=i),
                       seq.init_box)
        sub.undeclare()
    first = bad + 1 if fault == "lost" else bad
    # no box from a broken chain: an error result per unit until the next keyframe...
    for i in range(first, 2 * GOP):
        assert got[i].status == "error" and got[i].code == "decode_error", i
        assert got[i].track_state is None
    assert "lost" in got[first].message if fault == "lost" else "damaged" in got[first].message
    assert "keyframe" in got[first + 1].message
    # ...then tracking resumes on the keyframe, as the library on the frames it could decode
    kept = [p for i, p in enumerate(pictures) if i < bad or i >= 2 * GOP]
    want = library(kept, seq.init_box)
    tracked = [i for i in range(N) if i < bad or i >= 2 * GOP]
    assert all(got[i].status in ("initialized", "tracking") for i in tracked)
    np.testing.assert_allclose([got[i].box for i in tracked], [r.box for r in want], atol=1e-9)
    assert any(n.code == "decode_error" and n.stream_id == stream for n in notices)
    wait_until(lambda: service.metric("arcf_video_resyncs_total") >= resyncs + 1, timeout=30,
               what="the resync counted")
    assert service.metric("arcf_video_resyncs_total") == resyncs + 1


def test_garbage_on_the_video_key_is_refused_and_the_stream_goes_on(service, clip) -> None:
    seq, units, _ = clip
    errors = service.metric("arcf_errors_total")
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        notices: list[ErrorMessage] = []
        sub = client.session.declare_subscriber(
            KeySpace().errors("fox-bad"),
            lambda s: notices.append(decode(s.payload.to_bytes())))
        import zenoh

        pub = client.session.declare_publisher("video/fox-bad/stream",
                                               congestion_control=zenoh.CongestionControl.BLOCK)
        results = client.results("fox-bad")
        client.start("fox-bad", seq.init_box, preset=PRESET)
        pub.put(b"\x00\x01not cdr at all")
        pub.put(compressed_video(units[0], "vp9", 1))  # a format the service cannot decode
        for i in range(GOP):
            pub.put(compressed_video(units[i], "h264", 1 + i))
        got = []
        deadline = time.monotonic() + 30
        while (not got or got[-1].frame_seq < GOP + 1) and time.monotonic() < deadline:
            try:
                got.append(results.get(timeout=1.0))
            except queue.Empty:
                continue
        sub.undeclare()
    # the two bad messages took the numbers 0 and 1; the video starts at the keyframe (2); the
    # units queued behind it are all decoded, and the newest picture is the one tracked
    assert got and got[0].status == "initialized" and got[0].frame_seq >= 2
    assert all(r.status == "tracking" for r in got[1:]) and got[-1].frame_seq == GOP + 1
    # both refused and counted; one notice (at most one a second per kind of error)
    assert [n.code for n in notices] == ["decode_error"] and "CDR" in notices[0].message
    wait_until(lambda: service.metric("arcf_errors_total") >= errors + 2, timeout=30,
               what="both refusals counted")


def test_overload_drops_tracking_work_not_decoder_state(service, clip) -> None:
    """All units at once, faster than a tracker keeps up with: every unit is decoded (no
    resync, no error), the trackers run on the newest pictures and say how many they skipped."""
    seq, units, _ = clip
    resyncs = service.metric("arcf_video_resyncs_total")
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        results = client.results("burst")
        client.start("burst", seq.init_box, preset="arcf-hc", frame_seq=0)
        for i, unit in enumerate(units):
            client.publish_frame("burst", data=unit, encoding="h264", seq=i)
        got = []
        deadline = time.monotonic() + 60
        while (not got or got[-1].frame_seq < N - 1) and time.monotonic() < deadline:
            try:
                got.append(results.get(timeout=1.0))
            except queue.Empty:
                continue
    assert got[0].status == "initialized" and got[-1].frame_seq == N - 1
    assert all(r.status == "tracking" for r in got[1:])
    # each result accounts for the pictures skipped before it: together, every unit
    assert sum(1 + r.dropped for r in got) == N - got[0].frame_seq
    # (the workers count in shared files before they publish: with the last result in, a
    # resync would show already)
    assert service.metric("arcf_video_resyncs_total") == resyncs

"""The service end to end: a real ``arcf-service`` process, a real Zenoh client on loopback,
real JPEG frames from the shared data, a real HTTP scrape of the metrics endpoint."""

from __future__ import annotations

import os
import re
import signal
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("zenoh")

import itertools
from collections.abc import Sequence

import arcf
from arcf.client import ServiceError, TrackingClient
from arcf.client.media.images import REGION_DECODING, decode_compressed
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.driver import Clip, Fleet, Pacing
from arcf.loadtools.procs import ServiceProcess as _Service
from arcf.loadtools.waiting import wait_until
from arcf.schemas import KeySpace, LastBoxes, decode
from arcf.service.scrape import by_label, fetch
from arcf.service.settings import ServiceSettings
from arcf.service.stages import STAGES

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]


@pytest.fixture(scope="module")
def service():
    svc = _Service("--max-payload", str(2 * 1024 * 1024))
    yield svc
    if svc.proc.poll() is None:
        svc.stop()


@pytest.fixture(scope="module")
def frames():
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    data = [p.read_bytes() for p in seq.frames[:25]]
    return seq, data


def _clip(seq, data: list[bytes], box=None) -> Clip:  # type: ignore[no-untyped-def]
    return Clip(seq.name, tuple(box or seq.init_box), tuple(data))


def _offline_run(preset: str, data: list[bytes], box) -> arcf.SequenceRun:
    """The library alone on the same bytes, decoded as a worker decodes them."""
    frames = (decode_compressed(d) for d in data)
    return arcf.run_sequence(arcf.create_tracker(preset), frames, box)


def _offline(preset: str, data: list[bytes], box) -> np.ndarray:
    return _offline_run(preset, data, box).boxes


def _lockstep(client, streams: dict[str, tuple[Clip, Sequence[str]]]) -> Fleet:
    """Each stream replays its clip in lock-step (frame i once every session answered frame
    i - 1) to sessions of the presets listed; the fleet is returned with its sessions live.

    Lock-step replay makes "one result per frame" independent of the machine's speed (a paced
    replay on a loaded machine legitimately drops frames: that is tested elsewhere)."""
    fleet = Fleet(client, [clip for clip, _ in streams.values()], pacing=Pacing.lock_step())
    for name, (clip, presets) in streams.items():
        fleet.add(names=[name], clip=clip, sessions=presets, frames=len(clip))
    assert fleet.wait_published(timeout=60) and fleet.settle(timeout=30)
    return fleet


def _got(fleet: Fleet, stream: str) -> list:
    return [r.result for r in fleet.ledger[stream].received]


def _collect(stream, n: int, timeout: float = 60.0) -> list:
    """The next ``n`` results about frames (or session ends). Stale notices are skipped:
    this file pauses between frames longer than the service's ``stale_after_s``
    (tests/service/test_stale.py is about them)."""
    out, deadline = [], time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        try:
            r = stream.get(timeout=1.0)
        except Exception:  # queue.Empty
            continue
        if r.status != "stale":
            out.append(r)
    return out


def test_results_equal_the_library_offline(service, frames) -> None:
    seq, data = frames
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client, \
            _lockstep(client, {"wb7": (_clip(seq, data), ["arcf-h"])}) as fleet:
        got = sorted(_got(fleet, "wb7"), key=lambda r: r.frame_seq)
    assert [r.frame_seq for r in got] == list(range(len(data)))
    assert got[0].status == "initialized" and all(r.status == "tracking" for r in got[1:])
    assert all(r.dropped == 0 for r in got)
    offline = _offline_run("arcf-h", data, seq.init_box).results
    np.testing.assert_allclose([r.box for r in got], [r.box for r in offline], atol=1e-9)
    # the track state, as the library judges it
    assert [r.track_state for r in got] == [r.state.value for r in offline]
    np.testing.assert_allclose([r.confidence for r in got], [r.confidence for r in offline],
                               atol=1e-12)
    assert got[0].confidence == 1.0 and all(0 <= r.confidence <= 1 for r in got)
    # the re-acquisition events, as the library's (true on the event's frame, else absent)
    assert [r.reacquired is True for r in got] == [r.reacquired for r in offline]
    assert all(r.reacquired in (None, True) for r in got)
    for r in got:
        assert r.capture_ts_ns <= r.received_ts_ns <= r.published_ts_ns
        assert r.track_s > 0 and r.decode_s > 0


def test_two_streams_and_several_sessions_do_not_interfere(service, frames) -> None:
    seq, data = frames
    box_b = (seq.init_box[0] + 3, seq.init_box[1] + 2, seq.init_box[2], seq.init_box[3])
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client, \
            _lockstep(client, {"multi-a": (_clip(seq, data), ["arcf-h", "bacf"]),
                               "multi-b": (_clip(seq, data, box_b), ["arcf-h"])}) as fleet:
        got_a, got_b = _got(fleet, "multi-a"), _got(fleet, "multi-b")
        (a1, a2), (b1,) = fleet.ledger["multi-a"].sessions, fleet.ledger["multi-b"].sessions
    by_session: dict[str, list] = {}
    for r in got_a + got_b:
        by_session.setdefault(r.session_id, []).append(r)
    expected = {a1: _offline("arcf-h", data, seq.init_box),
                a2: _offline("bacf", data, seq.init_box),
                b1: _offline("arcf-h", data, box_b)}
    for sid, boxes in expected.items():
        rs = sorted(by_session[sid], key=lambda r: r.frame_seq)
        assert len(rs) == len(data)
        np.testing.assert_allclose([r.box for r in rs], boxes, atol=1e-9)


def test_frames_are_dropped_or_blocked_as_asked() -> None:
    with pytest.raises(ValueError, match="frame_congestion"):
        TrackingClient(connect=["tcp/127.0.0.1:9"], frame_congestion="maybe")


def test_control_errors_are_clear(service) -> None:
    with TrackingClient(connect=[service.endpoint]) as client:
        with pytest.raises(ServiceError) as e:
            client.stop("no-such-session")
        assert e.value.code == "unknown_session"
        with pytest.raises(ServiceError) as e:
            client.start("s", (10, 10, 20, 20), preset="kcf")
        assert e.value.code == "unknown_preset" and "arcf-hc" in str(e.value)
        with pytest.raises(ServiceError) as e:
            client.start("s", (10, 10, 20, 20), preset="arcf-h", overrides={"gamma": -1})
        assert e.value.code == "invalid_parameter"
        # A parameter that names a file on the host is the operator's, not a request's: the
        # service must not read /etc/passwd (or anything else) because a client asked.
        with pytest.raises(ServiceError) as e:
            client.start("s", (10, 10, 20, 20), preset="arcf-h",
                         overrides={"fhog_sse_table": "/etc/passwd"})
        assert e.value.code == "invalid_parameter" and "fhog_sse_table" in str(e.value)
        with pytest.raises(ValueError):  # the SDK refuses it before sending ...
            client.start("s", (10, 10, 0, 20), preset="arcf-h")
        # ... and the service refuses it too when a client sends it anyway
        import msgpack

        from arcf.schemas import ErrorMessage, decode

        for box, code in (([10, 10, 0, 20], "invalid_box"), ([1, 2, float("nan"), 4],
                                                               "invalid_box")):
            raw = msgpack.packb({"v": 1, "type": "start", "request_id": "r1", "stream_id": "s",
                                 "box": box, "preset": "arcf-h"}, use_bin_type=True)
            (reply,) = list(client.session.get(KeySpace().control(), payload=raw, timeout=5))
            err = decode(reply.ok.payload.to_bytes(), expected=ErrorMessage)
            assert getattr(err.code, "value", err.code) == code
            assert "box" in err.message
        (reply,) = list(client.session.get(KeySpace().control(), payload=b"\xc1junk", timeout=5))
        err = decode(reply.ok.payload.to_bytes(), expected=ErrorMessage)
        assert getattr(err.code, "value", err.code) == "malformed_message"
        status = client.status()
        assert status.workers == 2


def test_bad_input_is_counted_and_the_session_goes_on(service, frames) -> None:
    seq, data = frames
    keys = KeySpace()
    errors_before = service.metric("arcf_errors_total")
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        results = client.results("bad")
        errors = []
        sub = client.session.declare_subscriber(keys.errors("bad"), lambda s: errors.append(s))
        ack = client.start("bad", seq.init_box, preset="arcf-h", frame_seq=0)
        raw = client.session.declare_publisher(keys.frames("bad"))
        client.publish_frame("bad", data=data[0], seq=0)
        got = _collect(results, 1, timeout=30)
        raw.put(b"\x93garbage that is not a frame")  # malformed msgpack
        client.publish_frame("bad", data=b"\xff\xd8 not really a jpeg", seq=1)  # undecodable
        got += _collect(results, 1, timeout=30)
        client.publish_frame("bad", data=b"\0" * (3 * 1024 * 1024), seq=2)  # oversized
        client.publish_frame("nobody-tracks-this", data=data[0], seq=0)  # untracked stream
        for i in range(3, 8):
            client.publish_frame("bad", data=data[i - 2], seq=i)
            got += _collect(results, 1, timeout=30)
        got.sort(key=lambda r: r.frame_seq)
        client.stop(ack.session_id)
        sub.undeclare()
    statuses = {r.frame_seq: r.status for r in got}
    assert statuses[0] == "initialized"
    assert statuses[1] == "error"  # the undecodable frame, reported to the session
    assert all(statuses[i] == "tracking" for i in range(3, 8))  # and tracking went on
    assert len(errors) >= 3
    wait_until(lambda: service.metric("arcf_errors_total") >= errors_before + 4, timeout=30,
               what="four errors counted")


def test_metrics_count_what_was_sent(service, frames) -> None:
    seq, data = frames
    before_results = service.metric("arcf_results_published_total")
    before_frames = service.metric("arcf_frames_processed_total")
    before_decoded = by_label(fetch(service.metrics_url), "arcf_frames_decoded_total", "extent")
    before_waits = service.metric("arcf_queue_wait_seconds_count")
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client, \
            _lockstep(client, {"count": (_clip(seq, data[:10]), ["bacf"])}) as fleet:
        got = _got(fleet, "count")
    assert len(got) == 10
    wait_until(lambda: service.metric("arcf_results_published_total") - before_results >= 10
               and service.metric("arcf_frames_processed_total") - before_frames >= 10
               and service.metric("arcf_end_to_end_latency_seconds_count") >= 10, timeout=30,
               what="the ten frames counted")
    assert service.metric("arcf_results_published_total") - before_results == 10
    assert service.metric("arcf_frames_processed_total") - before_frames == 10
    assert service.metric("arcf_end_to_end_latency_seconds_count") >= 10
    # every frame's wait in its stream's queue, once
    assert service.metric("arcf_queue_wait_seconds_count") - before_waits == 10
    # the first frame decoded whole (the session starts on it), the others only where the
    # tracker reads them (a small target: bacf's windows cover a fraction of the frame)
    decoded = by_label(fetch(service.metrics_url), "arcf_frames_decoded_total", "extent")
    delta = {k: decoded.get(k, 0.0) - before_decoded.get(k, 0.0) for k in ("region", "whole")}
    assert delta["region"] + delta["whole"] == 10 and delta["whole"] >= 1
    if REGION_DECODING:
        assert delta["region"] >= 5, delta
    text = urllib.request.urlopen(service.metrics_url, timeout=5).read().decode()
    assert "count" not in re.findall(r'stream="([^"]+)"', text)  # no per-stream labels
    # every process reports its resident memory (what an operator watches for leaks; a
    # worker sets it once a second, so a service just started may not have yet)
    memory: dict[str, float] = {}

    def reported() -> bool:
        memory.update(by_label(fetch(service.metrics_url), "arcf_process_resident_bytes",
                               "process"))
        return len(memory) == 3 and all(v > 0 for v in memory.values())

    wait_until(reported, timeout=30, what="every process's resident memory")
    assert set(memory) == {"main", "worker-0", "worker-1"}
    assert all(20e6 < v < 2e9 for v in memory.values()), memory
    # where the workers' CPU went, by stage (added once a second): JPEG frames are received,
    # parsed, decoded, tracked and published; nothing is a video picture to convert
    stages: dict[str, float] = {}

    def staged() -> bool:
        stages.update(by_label(fetch(service.metrics_url), "arcf_stage_cpu_seconds_total",
                               "stage"))
        return all(stages.get(k, 0.0) > 0 for k in ("receive", "parse", "decode", "track",
                                                     "publish", "metrics"))

    wait_until(staged, timeout=30, what="every stage's CPU time reported")
    assert set(stages) <= set(STAGES) and stages.get("convert", 0.0) == 0.0


def test_flooded_stream_drops_are_accounted_and_other_streams_unaffected(service, frames) -> None:
    """A stream published faster than its tracker runs keeps only the newest frames; every
    frame is either tracked or counted in the next result's ``dropped``. A paced stream on the
    same service meanwhile gets every one of its frames."""
    seq, data = frames
    n_flood = 60
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        flood, calm = client.results("flood"), client.results("calm")
        a = client.start("flood", seq.init_box, preset="arcf-hc", frame_seq=0)
        b = client.start("calm", seq.init_box, preset="bacf", frame_seq=0)
        calm_got = []
        for i in range(n_flood):  # as fast as possible: far faster than arcf-hc runs
            client.publish_frame("flood", data=data[i % len(data)], seq=i)
            if i % 6 == 0:  # the calm stream, in lock-step at its own pace
                client.publish_frame("calm", data=data[(i // 6) % len(data)], seq=i // 6)
                calm_got += _collect(calm, 1, timeout=30)
        flood_got = []
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and (not flood_got or
                                                flood_got[-1].frame_seq < n_flood - 1):
            flood_got += _collect(flood, 1, timeout=2)
        client.stop(a.session_id)
        client.stop(b.session_id)
    seqs = [r.frame_seq for r in flood_got]
    assert seqs == sorted(seqs) and seqs[-1] == n_flood - 1  # the newest frame is never lost
    # accounting: frames before the first result, plus each gap, equals what was skipped
    for prev, cur in itertools.pairwise(flood_got):
        assert cur.dropped == cur.frame_seq - prev.frame_seq - 1
    skipped = flood_got[0].frame_seq + sum(r.dropped for r in flood_got[1:])
    assert skipped + len(flood_got) == n_flood
    assert skipped > 0  # it really was flooded
    assert [r.frame_seq for r in calm_got] == list(range(len(calm_got)))
    assert all(r.dropped == 0 for r in calm_got)


def test_wrong_schema_version_is_counted(service) -> None:
    import msgpack

    keys = KeySpace()
    before = service.metric("arcf_errors_total")
    with TrackingClient(connect=[service.endpoint]) as client:
        ack = client.start("version", (10, 10, 20, 20), preset="bacf")
        client.session.put(keys.frames("version"), msgpack.packb(
            {"v": 2, "type": "frame", "stream_id": "version", "seq": 0, "capture_ts_ns": 1,
             "encoding": "jpeg", "payload": b"x"}, use_bin_type=True))

        def metrics() -> str:
            return urllib.request.urlopen(service.metrics_url, timeout=5).read().decode()

        wait_until(lambda: 'arcf_errors_total{kind="unsupported_version"}' in metrics(),
                   timeout=30, what="the version-2 frame counted as unsupported_version")
        client.stop(ack.session_id)
    assert service.metric("arcf_errors_total") >= before + 1


def test_a_killed_worker_is_replaced_and_its_sessions_resume(frames) -> None:
    seq, data = frames
    svc = _Service()
    try:
        # two streams: least-loaded placement puts them on different workers
        s0, s1 = "kill-0", "kill-1"
        keys = KeySpace()
        with TrackingClient(connect=[svc.endpoint], frame_congestion="block") as client:
            r0, r1 = client.results(s0), client.results(s1)
            notices: list = []
            boxes: list[LastBoxes] = []
            box_sub = client.session.declare_subscriber(
                keys.all_last_boxes(), lambda x: boxes.append(decode(x.payload.to_bytes())))

            def boxed_at(frame: int) -> set[str]:
                """Streams whose session's box of ``frame`` was put."""
                sids = {e.session_id for m in list(boxes) for e in m.boxes
                        if e.frame_seq == frame}
                return {st.stream_id for st in client.status().sessions
                        if st.session_id in sids}

            subs = [client.session.declare_subscriber(keys.errors(s), lambda x: notices.append(
                str(x.key_expr))) for s in (s0, s1)]
            first = _clip(seq, data[:3])
            _lockstep(client, {s0: (first, ["bacf"]), s1: (first, ["bacf"])})
            for r in (r0, r1):  # the same results, queued here for the steps below
                assert [x.frame_seq for x in _collect(r, 3, timeout=30)] == [0, 1, 2]
            # frame 2's boxes reach the instance within last_box_period_ms, though no frame
            # follows: the worker wakes to put them
            wait_until(lambda: {s0, s1} <= boxed_at(2), timeout=30,
                       what="the last boxes of frame 2 put")
            victim = sorted(svc.workers)[0]
            os.kill(victim, signal.SIGKILL)
            wait_until(lambda: bool(notices), timeout=60, what="a notice about the lost worker")
            assert len(notices) == 1  # exactly one stream was on the killed worker
            dead_stream = s0 if notices[0] == keys.errors(s0) else s1
            alive_stream, alive_results = (s1, r1) if dead_stream == s0 else (s0, r0)
            dead_results = r0 if dead_stream == s0 else r1
            # the other stream's session never noticed
            for i in range(3, 8):
                client.publish_frame(alive_stream, data=data[i], seq=i)
                (r,) = _collect(alive_results, 1, timeout=30)
                assert r.frame_seq == i and r.status == "tracking"
            # the lost session resumes on a live worker from its last box (frame 2's)
            resumed = None
            i = 3
            # a deadline, not a figure: the session may land on the replacement worker, which
            # may take the service's own start-up allowance to be ready (compiling its kernels
            # where no cache exists, on a loaded machine)
            deadline = time.monotonic() + ServiceSettings().worker_start_s + 30
            while resumed is None and time.monotonic() < deadline:
                client.publish_frame(dead_stream, data=data[i % len(data)], seq=i)
                for r in _collect(dead_results, 1, timeout=0.5):  # the stimulus's pace
                    if r.status == "resumed":
                        resumed = r
                i += 1
            assert resumed is not None and resumed.frame_seq >= 3
            assert resumed.dropped == resumed.frame_seq - 3  # frames before it, counted
            client.publish_frame(dead_stream, data=data[i % len(data)], seq=i)
            (after,) = _collect(dead_results, 1, timeout=30)
            assert after.status == "tracking" and after.frame_seq == i
            for s in [*subs, box_sub]:
                s.undeclare()
        assert svc.metric("arcf_errors_total") >= 1
        assert svc.metric("arcf_sessions_taken_over_total") == 1
        causes = by_label(fetch(svc.metrics_url), "arcf_worker_deaths_total", "cause")
        assert causes == {"SIGKILL": 1}
    finally:
        assert svc.stop() == 0


def test_reinit_numpy_frames_and_callbacks(service, frames) -> None:
    """Raw BGR frames published from numpy arrays (exact pixels), results by callback, and a
    re-initialisation mid-stream that matches a library tracker re-initialised on that frame."""
    seq, data = frames
    # half-size frames: a raw 1280x720 BGR frame (2.8 MB) exceeds this service's 2 MiB limit
    images = [cv2.resize(cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_COLOR), (640, 360),
                         interpolation=cv2.INTER_AREA) for d in data[:8]]
    init_box = tuple(v / 2 for v in seq.init_box)
    new_box = tuple(float(v) / 2 for v in seq.groundtruth[4])
    received: list = []
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        sub = client.results("raw", callback=received.append)
        ack = client.start("raw", init_box, preset="arcf-h", frame_seq=0)
        for i, image in enumerate(images):
            if i == 4:
                client.reinit(ack.session_id, new_box, frame_seq=4)
            client.publish_frame("raw", image, encoding="bgr8", seq=i)
            wait_until(lambda i=i: any(r.frame_seq == i and r.track_state
                                       for r in list(received)), timeout=30,
                       what=f"frame {i} tracked")
        client.stop(ack.session_id)
        # the session's last result: it stopped
        wait_until(lambda: any(r.status == "stopped" for r in list(received)), timeout=30,
                   what="the session's stopped result")
        sub.close()
    *received, last = [r for r in received if r.status != "stale"]  # about frames, and the end
    assert str(getattr(last.status, "value", last.status)) == "stopped"
    assert last.frame_seq == len(images) - 1 and last.code is None
    t = arcf.create_tracker("arcf-h")
    expected = [t.init(images[0], init_box).box]
    expected += [t.update(im).box for im in images[1:4]]
    expected += [t.init(images[4], new_box).box]
    expected += [t.update(im).box for im in images[5:]]
    got = sorted(received, key=lambda r: r.frame_seq)
    assert [str(getattr(r.status, "value", r.status)) for r in got] == (
        ["initialized"] + ["tracking"] * 3 + ["reinitialized"] + ["tracking"] * 3)
    np.testing.assert_allclose([r.box for r in got], expected, atol=1e-9)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signals_stop_everything(sig) -> None:
    svc = _Service()
    workers = svc.workers
    assert len(workers) == 2
    svc.proc.send_signal(sig)
    assert svc.proc.wait(timeout=30) == 0

    def gone(pid: int) -> bool:
        try:
            return "zombie" in Path(f"/proc/{pid}/status").read_text().lower()
        except FileNotFoundError:
            return True

    wait_until(lambda: all(gone(pid) for pid in workers), timeout=30,
               what=f"workers {workers} ended")


def test_limits_stale_frames_and_bombs_are_refused_counted_and_harmless(frames, png_bomb) -> None:
    """Each refusal is a counted error with a clear code, and the sessions go on."""

    seq, data = frames
    svc = _Service("--max-stream-fps", "4", "--max-sessions", "2", "--max-pixels", "2000000")
    try:
        with TrackingClient(connect=[svc.endpoint], frame_congestion="block") as client:
            errors: list[str] = []  # the SDK's watch of what the service refuses
            watch = client.errors("lim", callback=lambda m: errors.append(m.code.value))
            results = client.results("lim")
            client.start("lim", seq.init_box, preset="bacf", frame_seq=0)
            client.start("lim-2", seq.init_box, preset="bacf")
            with pytest.raises(ServiceError) as refused:  # max_sessions (2 per instance)
                client.start("lim-3", seq.init_box, preset="bacf")
            assert refused.value.code == "limit_exceeded"
            assert "max_sessions" in str(refused.value)
            client.publish_frame("lim", data=data[0], seq=0)
            assert [r.status for r in _collect(results, 1, timeout=30)] == ["initialized"]
            time.sleep(1.0)  # the stimulus: the rate budget refills
            # a decompression bomb: refused from its header, an error result, no decoding
            client.publish_frame("lim", data=png_bomb(4000, 4000), encoding="png", seq=1)
            (bomb,) = _collect(results, 1, timeout=30)
            assert bomb.status == "error" and "pixels" in (bomb.message or "")
            assert bomb.track_state is None and bomb.confidence is None  # no box, no state
            # a duplicate and an out-of-order frame: refused, not tracked
            client.publish_frame("lim", data=data[1], seq=1)
            client.publish_frame("lim", data=data[0], seq=0)
            time.sleep(1.0)  # the stimulus: the rate budget refills
            client.publish_frame("lim", data=data[2], seq=2)
            (ok,) = _collect(results, 1, timeout=30)
            assert ok.frame_seq == 2 and ok.status == "tracking"
            # a flood above max_stream_fps: the excess is refused, and tracking goes on
            time.sleep(1.5)  # the stimulus: the rate budget refills to a whole second's (4)
            t_flood = time.monotonic()
            for i in range(3, 23):
                client.publish_frame("lim", data=data[i], seq=i)
                time.sleep(0.01)  # the stimulus: 20 frames at up to 100 frames/s
            sent_s = time.monotonic() - t_flood
            # then one frame every 0.5 s (within the limit) until one is answered: frames of a
            # stream pass the intake in order and results come in order, so every answer to
            # the flood is in by then
            got, seq_next, deadline = [], 23, time.monotonic() + 60
            while not any(r.frame_seq >= 23 for r in got):
                assert time.monotonic() < deadline, "no frame after the flood answered in 60 s"
                client.publish_frame("lim", data=data[seq_next % len(data)], seq=seq_next)
                seq_next += 1
                got += _collect(results, 1, timeout=0.5)  # the stimulus's pace
            markers = seq_next - 23
            got = [r for r in got if r.frame_seq < 23]
            # within one second's budget (4) and its refill while the flood arrived (as long
            # as it took to send, plus a second of delivery on a slow machine)
            assert 1 <= len(got) <= 4 + 4 * (sent_s + 1.0), (len(got), sent_s)
            assert all(r.status == "tracking" for r in got)
            codes: list[str] = []

            def noticed() -> bool:
                codes[:] = list(errors)
                return all(c in codes for c in ("image_too_large", "stale_frame",
                                                "rate_limited"))

            wait_until(noticed, timeout=30, what=f"the three refusals noticed ({codes})")
            watch.close()
            assert watch.malformed == 0
        # each refusal counted under its code: the refused start, two stale frames, the bomb,
        # then the flood's excess, each one of the frames without a result (the others were
        # dropped for the newest, and counted)
        from arcf.service.scrape import by_label, fetch

        kinds = by_label(fetch(svc.metrics_url), "arcf_errors_total", "kind")
        assert kinds["limit_exceeded"] == 1 and kinds["stale_frame"] == 2
        assert kinds["image_too_large"] == 1
        # (of the refusals, the frames after the flood account for at most markers - 1)
        assert kinds["rate_limited"] - (markers - 1) >= 1
        assert kinds["rate_limited"] <= 20 - len(got) + markers - 1
    finally:
        assert svc.stop() == 0


def test_sigterm_finishes_in_flight_frames_and_sends_final_statuses(frames) -> None:
    seq, data = frames
    svc = _Service()
    with TrackingClient(connect=[svc.endpoint], frame_congestion="block") as client:
        results = client.results("bye")
        fleet = _lockstep(client, {"bye": (_clip(seq, data[:3]), ["bacf", "arcf-h"])})
        assert len(_got(fleet, "bye")) == 6
        assert len(_collect(results, 6, timeout=30)) == 6
        svc.proc.send_signal(signal.SIGTERM)
        assert svc.proc.wait(timeout=60) == 0  # it ends by itself (a deadline, not a figure)
        final = _collect(results, 2, timeout=30)
    assert len(final) == 2 and {r.status for r in final} == {"stopped"}
    assert all(r.frame_seq == 2 and "shutting down" in (r.message or "") for r in final)


def test_workers_not_ready_in_time_exit_with_the_reason_instead_of_hanging() -> None:
    """A service whose workers miss the start-up deadline (here: an impossible one) exits
    non-zero saying why; it never sits alive without having printed "ready"."""
    with pytest.raises(RuntimeError) as e:
        _Service(workers=1, metrics=False, env={"ARCF_SERVICE_WORKER_START_S": "0.001"})
    assert "exit code 1" in str(e.value)
    assert "start-up failed: workers not ready" in str(e.value)

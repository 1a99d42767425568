"""``arcf-record`` against a real service: every frame and every result of a stream lands in
MCAP files an MCAP reader reads back, in Foxglove's schemas (CDR, ros2msg); the recording
re-scores as the library's run on the same frames; disk use stays within its cap."""

from __future__ import annotations

import json
import queue
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zenoh")
pytest.importorskip("mcap")

from mcap.reader import make_reader

import arcf
from arcf.adapters.record import Recorder
from arcf.client import TrackingClient, foxglove
from arcf.client.media.images import decode_compressed
from arcf.eval.metrics import score_sequence
from arcf.eval.recording import score_recording
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.video import decode_video, encode_video
from arcf.loadtools.waiting import wait_until

pytestmark = pytest.mark.integration
N = 20


@pytest.fixture(scope="module")
def clip(wakeboard7):
    return wakeboard7, [p.read_bytes() for p in wakeboard7.frames[:N]]


@pytest.fixture(scope="module")
def service():
    svc = ServiceProcess(workers=1)
    yield svc
    svc.stop()


def replay(client: TrackingClient, stream: str, frames: list[bytes], box, presets: list[str],
           encoding: str = "jpeg", recorder: Recorder | None = None) -> list:
    """Sessions of ``presets`` on the stream; frame i sent once every session answered i - 1.
    With a ``recorder``, waits until it has recorded every frame and every result too."""
    results = client.results(stream)
    for preset in presets:
        client.start(stream, box, preset=preset, frame_seq=0)
    got: list = []
    stale = 0
    for i, data in enumerate(frames):
        client.publish_frame(stream, data=data, encoding=encoding, seq=i)
        deadline = time.monotonic() + 30
        while sum(r.frame_seq == i for r in got) < len(presets) and time.monotonic() < deadline:
            try:
                r = results.get(timeout=1.0)
            except queue.Empty:
                continue
            if r.status != "stale":  # a notice about no frame (a stall over a second)
                got.append(r)
            else:
                stale += 1
    if recorder is not None:  # the recorder hears the last result too
        wait_until(lambda: recorder.frames >= len(frames)
                   and recorder.results >= len(got) + stale, timeout=30,
                   what="every frame and result recorded")
    return got


def messages(paths: list[Path]) -> dict[str, list]:
    by_topic: dict[str, list] = {}
    for path in paths:
        with open(path, "rb") as f:
            for schema, channel, message in make_reader(f).iter_messages():
                by_topic.setdefault(channel.topic, []).append((schema, channel, message))
    return by_topic


def test_every_frame_and_result_is_recorded_in_foxglove_schemas(service, clip,
                                                                tmp_path: Path) -> None:
    seq, frames = clip
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        with Recorder(client, "rec", tmp_path) as recorder:
            got = replay(client, "rec", frames, seq.init_box, ["bacf", "arcf-h"],
                         recorder=recorder)
        files = recorder.files
    assert len(got) == 2 * N and recorder.frames == N
    topics = messages(files)
    images = topics["/arcf/rec/image"]
    schema, channel, _ = images[0]
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        "foxglove_msgs/CompressedImage", "ros2msg", "cdr")
    assert "MSG: builtin_interfaces/Time" in schema.data.decode()
    decoded = [foxglove.deserialize(m.data, foxglove.COMPRESSED_IMAGE) for _, _, m in images]
    assert [bytes(d.data) for d in decoded] == frames  # every frame, as sent
    assert all(d.format == "jpeg" and d.frame_id == "rec" for d in decoded)
    results = [json.loads(m.data) for _, _, m in topics["/arcf/rec/results"]]
    assert recorder.results == len(results)  # every result recorded, stale notices too
    results = [r for r in results if r["status"] != "stale"]  # (a stall over a second)
    assert len(results) == 2 * N
    by_key = {(r.session_id, r.frame_seq): r for r in got}
    for r in results:
        np.testing.assert_allclose(r["box"], by_key[r["session_id"], r["frame_seq"]].box)
    # each session's boxes as annotations, on the timestamp of the frame they belong to
    for sid in {r.session_id for r in got}:
        notes = topics[f"/arcf/rec/sessions/{sid}/annotations"]
        assert len(notes) == N
        for _, _, m in notes:
            a = foxglove.deserialize(m.data, foxglove.IMAGE_ANNOTATIONS)
            (box,) = a.points
            r = next(r for r in got if r.session_id == sid and
                     r.capture_ts_ns == m.publish_time)
            x, y, w, h = r.box
            assert box.type == 2 and [(p.x, p.y) for p in box.points] == [
                (x - 1, y - 1), (x - 1 + w, y - 1), (x - 1 + w, y - 1 + h), (x - 1, y - 1 + h)]
            assert a.texts[0].text.startswith(sid[:8])


def test_readers_nobody_here_wrote_read_every_message(service, clip, tmp_path: Path) -> None:
    """Foxglove's own ros2msg decoder (mcap-ros2-support) decodes every image and annotation
    from the schema text the file carries, and every result validates against the JSON Schema
    the file carries (the jsonschema package): a viewer needs nothing of ours."""
    jsonschema = pytest.importorskip("jsonschema")
    ros2 = pytest.importorskip("mcap_ros2.decoder")
    seq, frames = clip
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        with Recorder(client, "other", tmp_path) as recorder:
            got = replay(client, "other", frames, seq.init_box, ["bacf"], recorder=recorder)
        files = recorder.files
    factory = ros2.DecoderFactory()
    decoded: dict[str, list] = {}
    for topic, entries in messages(files).items():
        for schema, channel, message in entries:
            if channel.message_encoding == "json":
                assert schema.encoding == "jsonschema"
                body = json.loads(message.data)
                jsonschema.validate(body, json.loads(schema.data))
                decoded.setdefault(topic, []).append(body)
            else:
                decoder = factory.decoder_for(channel.message_encoding, schema)
                assert decoder is not None, (channel.message_encoding, schema.encoding)
                decoded.setdefault(topic, []).append((message, decoder(message.data)))
    images = decoded["/arcf/other/image"]
    assert [bytes(m.data) for _, m in images] == frames
    for raw, m in images:  # the header's stamp is the frame's capture time
        assert m.format == "jpeg" and m.frame_id == "other"
        assert m.timestamp.sec * 10**9 + m.timestamp.nanosec == raw.publish_time
    (sid,) = {r.session_id for r in got}
    notes = decoded[f"/arcf/other/sessions/{sid}/annotations"]
    assert len(notes) == N
    by_time = {r.capture_ts_ns: r for r in got}
    for raw, a in notes:
        x, y, w, h = by_time[raw.publish_time].box
        (shape,) = a.points
        assert [(p.x, p.y) for p in shape.points] == [
            (x - 1, y - 1), (x - 1 + w, y - 1), (x - 1 + w, y - 1 + h), (x - 1, y - 1 + h)]
    results = [r for r in decoded["/arcf/other/results"] if r["status"] != "stale"]
    assert sorted(r["frame_seq"] for r in results) == list(range(N))


def test_a_recording_rescores_as_the_library_on_the_same_frames(service, clip,
                                                                tmp_path: Path) -> None:
    seq, frames = clip
    gt = np.asarray(seq.groundtruth[:N], dtype=float)
    gt_file = tmp_path / "gt.txt"
    gt_file.write_text("".join(",".join(f"{v:g}" for v in row) + "\n" for row in gt))
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client, \
            Recorder(client, "rescore", tmp_path / "rec") as recorder:
        replay(client, "rescore", frames, seq.init_box, ["bacf"], recorder=recorder)
        # the stream has ended: its session's stale notice is recorded too, and repeats the
        # last frame's number without being about it (it must not erase that frame's box)
        wait_until(lambda: recorder.results > N, timeout=30, what="the stale notice recorded")
    (score,) = score_recording(recorder.files, gt_file).values()
    library = arcf.run_sequence(arcf.create_tracker("bacf"),
                                (decode_compressed(f) for f in frames), seq.init_box).boxes
    want = score_sequence(library, gt)
    assert score.auc == pytest.approx(want.auc, abs=1e-12)
    assert score.precision20 == pytest.approx(want.precision20, abs=1e-12)


def test_a_video_stream_is_recorded_unit_by_unit(service, clip, tmp_path: Path) -> None:
    seq, frames = clip
    units = encode_video((decode_compressed(f) for f in frames), "h264", gop=10)
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client, \
            Recorder(client, "vid", tmp_path) as recorder:
        replay(client, "vid", units, seq.init_box, ["bacf"], encoding="h264",
               recorder=recorder)
    topics = messages(recorder.files)
    video = [foxglove.deserialize(m.data, foxglove.COMPRESSED_VIDEO)
             for _, _, m in topics["/arcf/vid/video"]]
    assert [bytes(v.data) for v in video] == units and {v.format for v in video} == {"h264"}
    assert len(decode_video(units)) == N
    assert len(topics["/arcf/vid/results"]) == N


def test_disk_use_is_capped_by_rotation(service, clip, tmp_path: Path) -> None:
    seq, frames = clip
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client, \
            Recorder(client, "rot", tmp_path, segment_bytes=256 << 10, keep=2) as recorder:
        replay(client, "rot", frames, seq.init_box, ["bacf"], recorder=recorder)
    kept = sorted(tmp_path.glob("rot-*.mcap"))
    assert len(recorder.files) > 3 and len(kept) == 2  # rotated, the oldest deleted
    assert kept == recorder.files[-2:]
    assert sum(p.stat().st_size for p in kept) < 2 * (256 << 10) + 2 * max(map(len, frames))
    topics = messages(kept)  # each kept file is complete and readable on its own
    images = topics["/arcf/rot/image"]
    assert [bytes(foxglove.deserialize(m.data, foxglove.COMPRESSED_IMAGE).data)
            for _, _, m in images] == frames[-len(images):]

"""``arcf-record``: a stream and its sessions' results into MCAP files that Foxglove opens.

    arcf-record cam1 --out recordings/                  # until Ctrl-C
    arcf-record cam1 --segment-mb 256 --keep 8          # at most 8 x 256 MB on disk
    arcf eval recording recordings/cam1-*.mcap groundtruth.txt   # re-score it

A recording is a listener: it takes nothing from the service's CPU. Per stream it writes

* ``/arcf/<stream>/image`` (``foxglove_msgs/msg/CompressedImage``: JPEG / PNG as sent; raw
  ``bgr8``/``gray8`` frames compressed to JPEG here) or ``/arcf/<stream>/video``
  (``foxglove_msgs/msg/CompressedVideo``: each H.264 / H.265 access unit as sent), stamped
  with the frame's capture time;
* ``/arcf/<stream>/sessions/<session>/annotations`` (``foxglove_msgs/msg/ImageAnnotations``):
  each session's box as a closed polyline in its own colour, and its state and confidence as
  text, stamped with the capture time of the frame they belong to, so that Foxglove's Image
  panel draws them on that frame (one topic per session: the panel shows one message per
  topic and time);
* ``/arcf/<stream>/results``: every ``result`` message as JSON (its JSON Schema from the wire
  contract), everything needed to re-score the run (``arcf eval recording``).

Frames and annotations are CDR with ``ros2msg`` schemas, the encoding Foxglove reads for its
own message types. Disk use is bounded: a file is closed at ``--segment-mb`` (a video
recording closes it before a keyframe, so every file starts decodable) and only the newest
``--keep`` files are kept.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.writer import CompressionType, Writer

from arcf.client import TrackingClient, foxglove
from arcf.client.media.encodings import codec_of, decode_image, encode_image
from arcf.schemas import Result, to_json
from arcf.schemas.export import message_schema

from ._command import add_service_arguments, connect
from .tap import DEFAULT_VIDEO_KEY, StreamTap, TapFrame

log = logging.getLogger(__name__)

#: session colours (RGBA, 0-1), in order of appearance; the live view uses the same ones
PALETTE = ((0.0, 1.0, 0.0, 1.0), (1.0, 0.0, 1.0, 1.0), (0.0, 1.0, 1.0, 1.0),
           (1.0, 0.6, 0.0, 1.0), (1.0, 1.0, 0.0, 1.0), (0.3, 0.5, 1.0, 1.0))
RESULTS_SCHEMA = "arcf.result"


def result_annotations(result: Result, colour: tuple[float, float, float, float]) -> Any:
    """A result's box and label as Foxglove ``ImageAnnotations`` (the wire's 1-based
    pixel boxes moved to Foxglove's 0-based image coordinates)."""
    fx = foxglove
    stamp = fx.time(result.capture_ts_ns)
    x, y, w, h = result.box
    x, y = x - 1.0, y - 1.0
    corners = [(x, y), (x + w, y), (x + w, y + h), (x, y + h)]
    rgba = fx.message("foxglove_msgs/msg/Color", r=colour[0], g=colour[1], b=colour[2],
                      a=colour[3])
    clear = fx.message("foxglove_msgs/msg/Color", r=0.0, g=0.0, b=0.0, a=0.0)
    shade = fx.message("foxglove_msgs/msg/Color", r=0.0, g=0.0, b=0.0, a=0.6)
    box = fx.message(
        "foxglove_msgs/msg/PointsAnnotation", timestamp=stamp, type=2,  # LINE_LOOP
        points=[fx.message("foxglove_msgs/msg/Point2", x=px, y=py) for px, py in corners],
        outline_color=rgba, outline_colors=[], fill_color=clear, thickness=3.0)
    state = result.track_state.value if result.track_state else result.status.value
    confidence = "" if result.confidence is None else f" {result.confidence:.2f}"
    text = fx.message(
        "foxglove_msgs/msg/TextAnnotation", timestamp=stamp,
        position=fx.message("foxglove_msgs/msg/Point2", x=x, y=max(y - 4.0, 0.0)),
        text=f"{result.session_id[:8]} {state}{confidence}", font_size=14.0,
        text_color=rgba, background_color=shade)
    return fx.message(fx.IMAGE_ANNOTATIONS, circles=[], points=[box], texts=[text])


class Recorder:
    """One stream (all its sessions, or one) into rotating MCAP files under ``out``."""

    def __init__(self, client: TrackingClient, stream_id: str, out: str | Path, *,
                 session_id: str | None = None, segment_bytes: int = 256 << 20,
                 keep: int = 8, video_key: str | None = DEFAULT_VIDEO_KEY) -> None:
        if segment_bytes < 64 << 10 or keep < 1:
            raise ValueError("segment_bytes must be at least 64 KiB and keep at least 1")
        self.stream_id = stream_id
        self.session_id = session_id
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.segment_bytes = segment_bytes
        self.keep = keep
        #: every file written, oldest first (the ones deleted by rotation included)
        self.files: list[Path] = []
        self.deleted: list[Path] = []
        self.frames = 0
        self.results = 0
        self._lock = threading.Lock()
        self._writer: Writer | None = None
        self._file: BinaryIO | None = None
        self._channels: dict[str, int] = {}
        self._colours: dict[str, tuple[float, float, float, float]] = {}
        self._closed = False
        self._tap = StreamTap(client, stream_id, self._on_frame, self._on_result, video_key)

    # ------------------------------------------------------------------ files
    def _open(self) -> None:
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        path = self.out / f"{self.stream_id}-{stamp}-{len(self.files):04d}.mcap"
        self._file = open(path, "wb")  # noqa: SIM115 (closed in _close_file)
        self._writer = Writer(self._file, chunk_size=min(1 << 20, self.segment_bytes // 8),
                              compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library="arcf-record")
        self._channels = {}
        self.files.append(path)
        while len(self.files) - len(self.deleted) > self.keep:
            oldest = self.files[len(self.deleted)]
            oldest.unlink(missing_ok=True)
            self.deleted.append(oldest)
        log.info("recording %s into %s", self.stream_id, path)

    def _close_file(self) -> None:
        if self._writer is not None:
            self._writer.finish()
            assert self._file is not None
            self._file.close()
        self._writer, self._file = None, None

    def _channel(self, topic: str, schema: str, encoding: str, data: bytes,
                 message_encoding: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            assert self._writer is not None
            schema_id = self._writer.register_schema(schema, encoding, data)
            channel = self._channels[topic] = self._writer.register_channel(
                topic, message_encoding, schema_id)
        return channel

    def _ros2_channel(self, topic: str, ros_type: str) -> int:
        return self._channel(topic, ros_type.replace("/msg/", "/"), "ros2msg",
                             foxglove.definition(ros_type).encode(), "cdr")

    def _write(self, channel: int, data: bytes, stamp_ns: int) -> None:
        assert self._writer is not None
        self._writer.add_message(channel, log_time=time.time_ns(), data=data,
                                 publish_time=max(stamp_ns, 0))

    # ------------------------------------------------------------------ messages
    def _on_frame(self, frame: TapFrame) -> None:
        with self._lock:
            if self._closed:
                return
            starts_segment = (not frame.is_video
                              or codec_of(frame.encoding).is_keyframe(frame.payload))
            if self._writer is None or (starts_segment and self._file is not None
                                        and self._file.tell() >= self.segment_bytes):
                self._close_file()
                self._open()
            stamp = foxglove.time(frame.capture_ts_ns)
            if frame.is_video:
                ros_type, topic, fmt = (foxglove.COMPRESSED_VIDEO,
                                        f"/arcf/{self.stream_id}/video", frame.encoding)
                data = frame.payload
            else:
                ros_type, topic = foxglove.COMPRESSED_IMAGE, f"/arcf/{self.stream_id}/image"
                fmt, data = _compressed(frame)
            message = foxglove.message(ros_type, timestamp=stamp, frame_id=self.stream_id,
                                       data=np.frombuffer(data, dtype=np.uint8), format=fmt)
            self._write(self._ros2_channel(topic, ros_type),
                        foxglove.serialize(message, ros_type), frame.capture_ts_ns)
            self.frames += 1

    def _on_result(self, result: Result) -> None:
        if self.session_id is not None and result.session_id != self.session_id:
            return
        with self._lock:
            if self._closed:
                return
            if self._writer is None:
                # a result can overtake its frame (they travel on different keys): the file
                # opens on whichever comes first, so that no result is lost
                self._open()
            results = self._channel(
                f"/arcf/{self.stream_id}/results", RESULTS_SCHEMA, "jsonschema",
                json.dumps(message_schema(Result)).encode(), "json")
            self._write(results, to_json(result), result.capture_ts_ns)
            self.results += 1
            if result.status.value in ("error", "stopped") or not all(
                    np.isfinite(result.box)):
                return
            colour = self._colours.setdefault(
                result.session_id, PALETTE[len(self._colours) % len(PALETTE)])
            topic = f"/arcf/{self.stream_id}/sessions/{result.session_id}/annotations"
            self._write(self._ros2_channel(topic, foxglove.IMAGE_ANNOTATIONS),
                        foxglove.serialize(result_annotations(result, colour),
                                           foxglove.IMAGE_ANNOTATIONS), result.capture_ts_ns)

    def close(self) -> None:
        """Stop listening and finish the current file (its summary and index written)."""
        self._tap.close()
        with self._lock:
            self._closed = True
            self._close_file()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _compressed(frame: TapFrame) -> tuple[str, bytes]:
    """A picture frame as CompressedImage's (format, data): as sent, or raw pixels as JPEG."""
    if codec_of(frame.encoding).kind == "image":
        return frame.encoding, frame.payload
    pixels, problem = decode_image(frame)
    if pixels is None:
        raise ValueError(problem[1] if problem else "raw frame could not be read")
    assert isinstance(pixels, np.ndarray)  # no region asked for: the whole picture
    return "jpeg", encode_image(pixels, "jpeg", 90)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="arcf-record", description=__doc__.splitlines()[0])
    ap.add_argument("stream", help="the stream id to record")
    ap.add_argument("--session", help="only this session's results (default: all of them)")
    ap.add_argument("--out", default="recordings", help="folder of the MCAP files")
    ap.add_argument("--segment-mb", type=float, default=256.0,
                    help="close a file past this size, MB (default 256)")
    ap.add_argument("--keep", type=int, default=8,
                    help="newest files kept; older ones are deleted (default 8)")
    ap.add_argument("--video-key", default=DEFAULT_VIDEO_KEY,
                    help="the service's video_key ('' for none)")
    add_service_arguments(ap)
    args = ap.parse_args(argv)
    if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", args.stream):
        ap.error(f"not a stream id: {args.stream!r}")
    client, stop = connect(args, log)
    if client is None:
        return 2
    with client, \
            Recorder(client, args.stream, args.out, session_id=args.session,
                     segment_bytes=int(args.segment_mb * (1 << 20)), keep=args.keep,
                     video_key=args.video_key or None) as recorder:
        while not stop.wait(5.0):
            log.info("%d frames, %d results recorded", recorder.frames, recorder.results)
    log.info("done: %d frames, %d results in %s", recorder.frames, recorder.results,
             ", ".join(str(p) for p in recorder.files if p not in recorder.deleted))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

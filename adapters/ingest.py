"""Camera in: a real video source published as a named stream of a running service.

Gimbal cameras and companion computers deliver RTSP, RTP/UDP H.264 (QGroundControl's and
ArduPilot's convention: UDP port 5600, no SDP), MPEG-TS over UDP, or a V4L2 device.
:class:`Ingest` reads one of them and publishes every picture as a ``frame`` of the stream
(``<prefix>/streams/<stream>/frames``), so that any station can start a session on it:

* **H.264 / H.265 are passed through**, never re-encoded: each access unit the demuxer
  (FFmpeg, through PyAV) returns goes out as it came, in Annex B form (an MP4's length-prefixed
  units are converted by FFmpeg's ``*_mp4toannexb`` filter), with the parameter sets of the
  stream's configuration (an SDP's ``sprop-parameter-sets``) put in front of a keyframe that
  comes without them. The service decodes it (:mod:`arcf.client.media.video`).
* **MJPEG is passed through** as JPEG; anything else (raw video, VP8, a V4L2 webcam read with
  OpenCV) is decoded here and sent as JPEG.
* **Numbering says what was lost:** units are numbered consecutively. Whatever breaks the
  chain of decoded pictures (the source reopened after it stopped or its sender restarted,
  a unit FFmpeg marks corrupt, units skipped before the first keyframe after an opening)
  leaves a hole in the numbering: the service then drops its decoder state, counts the gap,
  and waits for the next keyframe, so no box is computed on a picture decoded from a broken
  reference. Every such event is counted here too (:attr:`Ingest.counts`).
* **Capture time** is the source's own presentation clock laid on the wall clock at the first
  unit (so network jitter does not move it), re-laid when the two drift more than a second
  apart (a sender restarted, a file looped).
* **A source that stops is waited for**, never fatal: a read that sees nothing for
  ``read_timeout_s`` closes the source and opens it again, with a log line when it is lost
  and when it is back. A source connected to (RTSP) is tried every ``retry_s`` at first, then
  less often (at most ``retry_max_s``); one that listens (RTP, MPEG-TS over UDP) is listened
  to again ``retry_s`` after each opening that heard nothing, since that opening waited.
  A file plays once (or ``loop``) at its own pace (or as fast as the link takes it).
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import av
import av.bitstream
import cv2
import numpy as np

from arcf.client import TrackingClient
from arcf.client.media.encodings import video_codec

from ._command import add_service_arguments, connect

log = logging.getLogger(__name__)

#: FFmpeg's codec name -> the frame ``encoding`` a unit of it is published with, unchanged
PASSED_THROUGH = {"h264": "h264", "hevc": "h265", "mjpeg": "jpeg"}
#: FFmpeg's report of RTP packets that never came (libavformat/rtpdec.c): the unit they
#: belonged to is damaged, whatever the packet flags say
_RTP_LOSS = re.compile(r"RTP: missed (\d+) packets")
#: the default RTP payload type of H.264 / H.265 senders without an SDP (QGroundControl's
#: and ArduPilot's UDP video: GStreamer's ``rtph264pay`` default)
DEFAULT_PAYLOAD_TYPE = 96


@dataclass(frozen=True)
class Source:
    """What to open, and how.

    ``kind``: ``rtsp``, ``rtp`` (RTP over UDP, described by an SDP), ``mpegts`` (MPEG-TS over
    UDP), ``file`` or ``v4l2``. ``live`` sources are reopened when they stop; a file ends.
    """

    kind: str
    url: str
    format: str | None = None
    options: dict[str, str] = field(default_factory=dict)
    #: the SDP text for an ``rtp`` source given as ``rtp://HOST:PORT``
    sdp: str | None = None
    #: a UDP source with no address (``rtp://:PORT``, ``udp://:PORT``): it listens on every
    #: interface, so any host that reaches the port can send video into the stream
    everywhere: bool = False

    @property
    def live(self) -> bool:
        return self.kind != "file"

    @property
    def listens(self) -> bool:
        """Video is sent to a port here (RTP, MPEG-TS over UDP), nothing is connected to:
        each opening waits for the camera, so a failed one is retried without backing off."""
        return self.kind in ("rtp", "mpegts")

    def __str__(self) -> str:
        return self.url


def rtp_sdp(host: str, port: int, codec: str = "h264",
            payload_type: int = DEFAULT_PAYLOAD_TYPE) -> str:
    """The SDP a sender without one implies: RTP/AVP on ``port``, one video stream of
    ``codec`` (``h264`` or ``h265``) with the dynamic payload type and the 90 kHz clock every
    video RTP profile uses (RFC 6184, RFC 7798). Parameter sets must come in-band (GStreamer
    ``rtph264pay config-interval``; cameras send them before each keyframe)."""
    encoding = {"h264": "H264", "h265": "H265"}.get(codec)
    if encoding is None:
        raise ValueError(f"RTP without an SDP: codec must be h264 or h265, got {codec!r}")
    if not 96 <= payload_type <= 127:
        raise ValueError(f"a dynamic RTP payload type is 96..127, got {payload_type}")
    return (f"v=0\r\no=- 0 0 IN IP4 {host}\r\ns=arcf-ingest\r\nc=IN IP4 {host}\r\nt=0 0\r\n"
            f"m=video {port} RTP/AVP {payload_type}\r\n"
            f"a=rtpmap:{payload_type} {encoding}/90000\r\n")


def parse_source(text: str, *, rtsp_transport: str = "tcp", rtp_codec: str = "h264",
                 payload_type: int = DEFAULT_PAYLOAD_TYPE) -> Source:
    """A source from what an operator types:

    * ``rtsp://HOST[:PORT]/PATH`` (``rtsps://`` too): an RTSP server (a camera, a companion
      computer), interleaved over TCP by default (``rtsp_transport="udp"`` for RTP/UDP);
    * ``rtp://[HOST]:PORT``: RTP over UDP without an SDP, QGroundControl's convention
      (``rtp://:5600``), ``rtp_codec`` H.264 or H.265 with ``payload_type``;
    * ``PATH.sdp``: RTP described by an SDP file (what ``ffmpeg -f rtp`` prints);
    * ``udp://[HOST]:PORT``: MPEG-TS over UDP (``ffmpeg -f mpegts udp://...``);
    * ``/dev/videoN`` or ``v4l2:/dev/videoN``: a V4L2 device (read with OpenCV);
    * anything else: a file FFmpeg can read (MP4, MKV, TS, raw ``.h264``...).
    """
    if text.startswith(("rtsp://", "rtsps://")):
        if rtsp_transport not in ("tcp", "udp"):
            raise ValueError(f"rtsp_transport must be tcp or udp, got {rtsp_transport!r}")
        return Source("rtsp", text, options={"rtsp_transport": rtsp_transport, **_LIVE_PROBE})
    if text.startswith("rtp://"):
        m = re.fullmatch(r"rtp://@?([^:/]*):(\d+)/?", text)
        if m is None:
            raise ValueError(f"an RTP source is rtp://[HOST]:PORT, got {text!r}")
        host, port = m[1] or "0.0.0.0", int(m[2])
        if not 0 < port < 65536:
            raise ValueError(f"no UDP port {port}")
        return Source("rtp", text, "sdp", _SDP_OPTIONS,
                      sdp=rtp_sdp(host, port, rtp_codec, payload_type),
                      everywhere=host in ("0.0.0.0", ""))
    if text.endswith(".sdp"):
        return Source("rtp", text, "sdp", _SDP_OPTIONS)
    if text.startswith("udp://"):
        sep = "&" if "?" in text else "?"
        # a lost datagram is a gap FFmpeg reports, not a reason to stop reading
        return Source("mpegts", f"{text}{sep}overrun_nonfatal=1&fifo_size=65536", "mpegts",
                      dict(_LIVE_PROBE),
                      everywhere=re.match(r"udp://@?(0\.0\.0\.0)?:", text) is not None)
    if text.startswith("v4l2:") or text.startswith("/dev/video"):
        return Source("v4l2", text.removeprefix("v4l2:"))
    return Source("file", text)


#: how far past the stream's last tracked frame a restarted ingest numbers on: the frames
#: its last run sent that were still in flight (within the service's allowed jump, 30)
RESUME_MARGIN = 20
#: how long, and how often, a restarted ingest asks again for the last frame of a session
#: its worker has not reported yet (workers report once a second; later when busy)
RESUME_ASK_S, RESUME_ASK_EVERY_S = 5.0, 0.25
#: a live source is probed until its parameters are known (its first keyframe), for a second
#: at most, not FFmpeg's five, and not for 20 frames to guess a frame rate (every unit carries
#: its presentation time): its first picture, and a returning camera's, waits for the probe
_LIVE_PROBE = {"analyzeduration": "1000000", "fpsprobesize": "0"}
#: what an SDP may open: the SDP itself (from a file) and the RTP/UDP it names; RTP packets
#: reordered on the way are put back in order within 64
_SDP_OPTIONS = {"protocol_whitelist": "file,udp,rtp", "reorder_queue_size": "64",
                **_LIVE_PROBE}


class CaptureClock:
    """A unit's capture time (ns since the epoch) from its presentation time (s).

    The presentation clock is laid on the wall clock at the first unit, and re-laid when
    the two drift apart by more than ``slack_s`` (a restarted sender starts its clock
    again; a looped file does too). Units without a presentation time get the wall clock.
    """

    def __init__(self, slack_s: float = 1.0) -> None:
        self.slack_ns = int(slack_s * 1e9)
        self._anchor: tuple[float, int] | None = None
        self.relaid = 0

    def reset(self) -> None:
        self._anchor = None

    def stamp(self, pts_s: float | None, now_ns: int) -> int:
        if pts_s is None:
            return now_ns
        if self._anchor is not None:
            t = self._anchor[1] + int((pts_s - self._anchor[0]) * 1e9)
            if abs(t - now_ns) <= self.slack_ns:
                return t
            self.relaid += 1
        self._anchor = (pts_s, now_ns)
        return now_ns


@dataclass
class _Unit:
    """One picture to publish: an access unit as it came, or a decoded picture."""

    pts_s: float | None
    keyframe: bool
    #: the frame ``encoding`` of ``data``
    encoding: str = "jpeg"
    data: bytes | None = None
    image: np.ndarray | None = None
    corrupt: bool = False


class Ingest:
    """Publish ``source`` as stream ``stream_id`` of the service ``client`` reaches.

    Call :meth:`run` (blocking, until :meth:`close`) or :meth:`start` (in a thread).
    ``realtime``: a file plays at its own frame rate (a live source always comes at its own).
    ``read_timeout_s``: a live source with nothing to read for this long is closed and
    opened again. ``retry_s`` / ``retry_max_s``: the wait before reopening a source that
    failed, doubled at each failure in a row up to the maximum (1 s: a camera that comes
    back is read again within a second; an attempt costs a connection). A source that
    :attr:`~Source.listens` waits ``retry_s`` only: its opening already waited for the camera
    (``open_timeout_s``), and its port is deaf between two openings.
    """

    def __init__(self, client: TrackingClient, source: Source, stream_id: str, *,
                 realtime: bool = True, loop: bool = False, jpeg_quality: int = 90,
                 open_timeout_s: float = 10.0, read_timeout_s: float = 3.0,
                 retry_s: float = 0.25, retry_max_s: float = 1.0) -> None:
        if not 1 <= jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be within 1..100, got {jpeg_quality}")
        self.client = client
        self.source = source
        self.stream_id = stream_id
        self.realtime = realtime
        self.loop = loop
        self.jpeg_quality = jpeg_quality
        self.open_timeout_s = open_timeout_s
        self.read_timeout_s = read_timeout_s
        self.retry_s = retry_s
        self.retry_max_s = retry_max_s
        #: what happened: ``published``, ``keyframes``, ``opened``, ``reopened``,
        #: ``open_failed``, ``read_timeouts``, ``read_errors``, ``corrupt``,
        #: ``before_keyframe`` (skipped), ``gaps`` (holes left in the numbering),
        #: ``publish_errors``
        self.counts: Counter[str] = Counter()
        #: the picture size last seen (from the stream's parameters), or None
        self.size: tuple[int, int] | None = None
        self.clock = CaptureClock()
        self._seq = -1  # the last number given
        self._hole = False  # the next unit's number skips one
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sdp_path: str | None = None
        # FFmpeg's warnings (RTP packets missed) must reach the capture in ``_packets``
        if av.logging.get_level() is None:
            av.logging.set_level(av.logging.WARNING)

    # ------------------------------------------------------------------ running
    def start(self) -> Ingest:
        self._thread = threading.Thread(target=self.run, name=f"ingest-{self.stream_id}",
                                        daemon=True)
        self._thread.start()
        return self

    def close(self, timeout: float = 10.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self._sdp_path is not None:
            Path(self._sdp_path).unlink(missing_ok=True)

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def done(self) -> bool:
        """The source ended for good (a file played to its end without ``loop``)."""
        return self.counts["ended"] > 0

    def run(self) -> None:
        """Open, publish, reopen, until :meth:`close` (or a file's end)."""
        self._continue_numbering()
        failures = 0
        lost_at: float | None = None
        while not self._stop.is_set():
            before = self.counts["published"]
            try:
                self._play()
                if not self.source.live:
                    if not self.loop:
                        self.counts["ended"] += 1
                        log.info("ingest %s: %s played to its end (%d frames published)",
                                 self.stream_id, self.source, self.counts["published"])
                        return
                    self.clock.reset()
                    continue
                why = f"nothing for {self.read_timeout_s:g} s"
            except _OpenFailed as exc:
                why = str(exc)
            except Exception as exc:  # a source that broke in a way nobody foresaw
                self.counts["internal_errors"] += 1
                log.exception("ingest %s: %s failed", self.stream_id, self.source)
                why = f"internal error: {exc}"
            if self._stop.is_set():
                return
            if not self.source.live:  # a file that cannot be read: nothing to wait for
                self.counts["ended"] += 1
                log.error("ingest %s: %s: %s", self.stream_id, self.source, why)
                return
            self._hole = True  # whatever comes next is a new chain of pictures
            if self.counts["published"] > before or self.source.listens:
                failures = 0
            wait = min(self.retry_s * 2 ** failures, self.retry_max_s)
            failures += 1
            if lost_at is None or self.counts["published"] > before:
                lost_at = time.monotonic()
                again = ("listening for it again" if self.source.listens else
                         f"opening it again every {self.retry_max_s:.1f} s at most")
                log.warning("ingest %s: %s lost (%s); %s", self.stream_id, self.source, why,
                            again)
            self._stop.wait(wait)
            self.counts["reopened"] += 1

    def _continue_numbering(self) -> None:
        """Number on from the stream's last frame the service tracked (its sessions' last
        results), not from 0: a restarted ingest under a running session would otherwise
        send numbers the stream has passed, refused until its numbering is followed anew,
        and a box a pilot drew on the last frames would wait for a number not yet reached.
        No answer, or no session: from 0 (then nothing waits for a number).

        Workers report their sessions once a second: a session that has not been reported
        yet (``waiting``, no last frame) is asked about again for ``RESUME_ASK_S`` at most,
        so that an ingest restarted at once still finds the frame its stream is at."""
        deadline = time.monotonic() + RESUME_ASK_S
        while True:
            try:
                sessions = self.client.status(stream_id=self.stream_id).sessions
            except Exception as exc:  # no answer in time: the service follows a restart anyway
                log.info("ingest %s: numbering from 0 (no status from the service: %s)",
                         self.stream_id, exc)
                return
            last = max((s.last_seq for s in sessions if s.last_seq is not None), default=None)
            unreported = any(s.last_seq is None and s.state == "waiting" for s in sessions)
            if (last is not None or not unreported or time.monotonic() >= deadline
                    or self._stop.wait(RESUME_ASK_EVERY_S)):
                break
        if last is not None and last + RESUME_MARGIN > self._seq:
            # beyond the frames the last run sent that no result had answered yet; a jump
            # the service takes at once (it allows 30 frames more than a stream's rate could
            # have sent since its last), counted there as frames dropped
            self._seq = last + RESUME_MARGIN
            log.info("ingest %s: numbering on from frame %d (the stream's last tracked, %d)",
                     self.stream_id, self._seq + 1, last)

    # ------------------------------------------------------------------ reading
    def _play(self) -> None:
        """Publish the source's pictures until it ends or stops; raise ``_OpenFailed`` when
        it cannot be opened."""
        if self.source.kind == "v4l2":
            units: Iterator[_Unit] = self._v4l2_units()
        else:
            units = self._av_units()
        announced = False
        waiting_for_keyframe = True
        first_pts: float | None = None
        started = time.monotonic()
        for unit in units:
            if self._stop.is_set():
                return
            if not announced:
                announced = True
                self.counts["opened"] += 1
                log.info("ingest %s: reading %s (%s%s)", self.stream_id, self.source,
                         self.source.kind, f", {self.size[0]}x{self.size[1]}"
                         if self.size else "")
            if unit.corrupt:  # FFmpeg says so: a unit lost or damaged on the way
                self.counts["corrupt"] += 1
                self._hole = waiting_for_keyframe = True
                continue
            if waiting_for_keyframe and not unit.keyframe:
                self.counts["before_keyframe"] += 1
                self._hole = True
                continue
            waiting_for_keyframe = False
            if self.realtime and not self.source.live and unit.pts_s is not None:
                # a file at its own pace: each picture at its presentation time
                first_pts = unit.pts_s if first_pts is None else first_pts
                due = started + unit.pts_s - first_pts
                if self._stop.wait(max(0.0, due - time.monotonic())):
                    return
            self._publish(unit)

    def _open(self) -> tuple[Any, int]:
        """The opened container, and the RTP packets reported missing while it was probed."""
        source = self.source
        url = source.url
        if source.sdp is not None:
            if self._sdp_path is None:
                fd, self._sdp_path = tempfile.mkstemp(prefix="arcf-ingest-", suffix=".sdp")
                with os.fdopen(fd, "w") as f:
                    f.write(source.sdp)
            url = self._sdp_path
        try:
            with av.logging.Capture(local=True) as logs:
                container = av.open(url, format=source.format, options=dict(source.options),
                                    timeout=(self.open_timeout_s, self.read_timeout_s)
                                    if source.live else None)
        except (av.FFmpegError, OSError) as exc:
            self.counts["open_failed"] += 1
            raise _OpenFailed(f"cannot open: {exc}") from exc
        return container, self._lost(logs)

    def _lost(self, logs: Sequence[tuple[int, str, str]]) -> int:
        """RTP packets FFmpeg reported missing in ``logs`` (counted in ``lost_rtp``)."""
        lost = sum(int(m[1]) for _, _, text in logs if (m := _RTP_LOSS.search(text)))
        self.counts["lost_rtp"] += lost
        return lost

    def _packets(self, container: Any, stream: Any,
                 lost_in_probe: int) -> Iterator[tuple[Any, bool]]:
        """The stream's packets, each with whether it is damaged: flagged corrupt by the
        demuxer, or read while FFmpeg reported RTP packets missing. A loss shows in the unit
        being read or the next (the parser holds one), so both are taken as damaged; a loss
        while the source was being probed (its first packets are read ahead, then handed
        out) could be anywhere before the second keyframe.

        A live source silent for ``read_timeout_s`` ends the reading. PyAV's timeout stops
        FFmpeg's read, but H.264 and H.265 go through FFmpeg's parser, which holds the last
        unit until the next one begins: the stopped read hands that unit out instead of
        failing, and only the read after it fails, one more timeout later. A read that took
        the whole timeout therefore ends the reading after its unit."""
        demux = container.demux(stream)
        damaged_next = False
        suspect_keyframes = 2 if lost_in_probe else 0
        while True:
            began = time.monotonic()
            with av.logging.Capture(local=True) as logs:
                packet = next(demux, None)
            if packet is None:
                return
            timed_out = (self.source.live
                         and time.monotonic() - began >= self.read_timeout_s)
            lost = self._lost(logs)
            if packet.size == 0:
                continue
            if suspect_keyframes and packet.is_keyframe:
                suspect_keyframes -= 1
            yield packet, (packet.is_corrupt or damaged_next or lost > 0
                           or suspect_keyframes > 0)
            damaged_next = lost > 0
            if timed_out:
                self.counts["read_timeouts"] += 1
                return

    def _av_units(self) -> Iterator[_Unit]:
        container, lost_in_probe = self._open()
        try:
            if not container.streams.video:
                raise _OpenFailed("no video stream in it")
            stream = container.streams.video[0]
            ctx = stream.codec_context
            codec = ctx.name
            if ctx.width and ctx.height:
                self.size = (ctx.width, ctx.height)
            tb = float(stream.time_base) if stream.time_base else None
            if codec in ("h264", "hevc"):
                yield from self._access_units(container, stream, codec, tb, lost_in_probe)
                return
            decode = codec not in PASSED_THROUGH
            try:
                for packet, damaged in self._packets(container, stream, lost_in_probe):
                    pts = None if packet.pts is None or tb is None else packet.pts * tb
                    if not decode:
                        yield _Unit(pts, True, "jpeg", bytes(packet), corrupt=damaged)
                        continue
                    for picture in ctx.decode(packet):
                        self.size = (picture.width, picture.height)
                        ppts = None if picture.pts is None or tb is None else picture.pts * tb
                        yield _Unit(ppts, True, image=picture.to_ndarray(format="bgr24"))
            except av.FFmpegError as exc:  # a read timeout (ExitError) or a broken source
                self._read_failed(exc)
        finally:
            container.close()

    def _access_units(self, container: Any, stream: Any, codec: str, tb: float | None,
                      lost_in_probe: int) -> Iterator[_Unit]:
        """H.264 / H.265 access units as they came, in Annex B form."""
        extradata = bytes(stream.codec_context.extradata or b"")
        # MP4 / MKV keep parameter sets in the configuration and prefix units by length:
        # FFmpeg's filter writes start codes and puts the parameter sets in front of keyframes
        bsf = (av.bitstream.BitStreamFilterContext(f"{codec}_mp4toannexb", stream)
               if extradata[:1] == b"\x01" else None)
        wire = video_codec(PASSED_THROUGH[codec])
        assert wire is not None  # PASSED_THROUGH names the wire's video encodings
        params = ([] if bsf is not None else
                  [(k, u) for k, u in _units(extradata, codec) if k in wire.parameter_types])
        try:
            for packet, corrupt in self._packets(container, stream, lost_in_probe):
                pts = None if packet.pts is None or tb is None else packet.pts * tb
                for out in (bsf.filter(packet) if bsf is not None else [packet]):
                    data = bytes(out)
                    kinds = {k for k, _ in _units(data, codec)}
                    keyframe = bool(kinds & wire.keyframe_types)
                    if keyframe and params:  # out-of-band parameter sets, in front
                        data = b"".join(u for k, u in params if k not in kinds) + data
                    yield _Unit(pts, keyframe, PASSED_THROUGH[codec], data, corrupt=corrupt)
        except av.FFmpegError as exc:
            self._read_failed(exc)

    def _read_failed(self, exc: Exception) -> None:
        if isinstance(exc, av.ExitError):  # PyAV's read timeout: nothing came
            self.counts["read_timeouts"] += 1
        else:
            self.counts["read_errors"] += 1
            log.info("ingest %s: reading %s: %s", self.stream_id, self.source, exc)

    def _v4l2_units(self) -> Iterator[_Unit]:
        device = self.source.url
        if not os.path.exists(device):
            self.counts["open_failed"] += 1
            raise _OpenFailed(f"no device {device}")
        cap = cv2.VideoCapture(device, cv2.CAP_V4L2)
        try:
            if not cap.isOpened():
                self.counts["open_failed"] += 1
                raise _OpenFailed(f"{device} cannot be opened as a V4L2 camera")
            while not self._stop.is_set():
                ok, image = cap.read()
                if not ok:
                    self.counts["read_errors"] += 1
                    return
                self.size = (image.shape[1], image.shape[0])
                yield _Unit(None, True, image=image)
        finally:
            cap.release()

    # ------------------------------------------------------------------ publishing
    def _publish(self, unit: _Unit) -> None:
        if self._hole and self._seq >= 0:
            self._seq += 1  # the number nobody gets: the service resynchronises there
            self.counts["gaps"] += 1
        self._hole = False
        self._seq += 1
        capture = self.clock.stamp(unit.pts_s, time.time_ns())
        try:
            if unit.image is not None:
                self.client.publish_frame(self.stream_id, unit.image, seq=self._seq,
                                          capture_ts_ns=capture, quality=self.jpeg_quality)
            else:
                assert unit.data is not None
                self.client.publish_frame(self.stream_id, data=unit.data, encoding=unit.encoding,
                                          seq=self._seq, capture_ts_ns=capture, size=self.size)
        except Exception as exc:  # a unit above max_payload, a closed session
            self.counts["publish_errors"] += 1
            self._hole = True
            log.warning("ingest %s: frame %d not published: %s", self.stream_id, self._seq, exc)
            return
        self.counts["published"] += 1
        self.counts["keyframes"] += unit.keyframe

def _units(data: bytes, codec: str) -> list[tuple[int, bytes]]:
    """``data``'s NAL units (FFmpeg's ``codec``); none where it holds too many."""
    wire = video_codec(PASSED_THROUGH[codec])
    assert wire is not None  # PASSED_THROUGH names the wire's video encodings
    try:
        return wire.nal_units(data)
    except ValueError:
        return []


class _OpenFailed(Exception):
    """The source could not be opened (or holds no video)."""


# ---------------------------------------------------------------------------------- command
def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="arcf-ingest",
        description="Publish a camera's video (RTSP, RTP/UDP, MPEG-TS/UDP, a file or a V4L2 "
        "device) as a stream of a running arcf-service; H.264/H.265 pass through unchanged.",
        epilog="Sources: rtsp://HOST:PORT/PATH; rtp://:5600 (RTP H.264 without an SDP, "
        "QGroundControl's port); PATH.sdp; udp://:PORT (MPEG-TS); /dev/video0; a file.")
    ap.add_argument("source", help="what to read (see below)")
    ap.add_argument("--stream", required=True, help="the service's stream id to publish as")
    ap.add_argument("--rtsp-transport", choices=("tcp", "udp"), default="tcp",
                    help="RTSP: RTP interleaved over the TCP connection (default) or over UDP")
    ap.add_argument("--rtp-codec", choices=("h264", "h265"), default="h264",
                    help="rtp://: the codec the sender sends (default %(default)s)")
    ap.add_argument("--payload-type", type=int, default=DEFAULT_PAYLOAD_TYPE,
                    help="rtp://: the RTP payload type (default %(default)s)")
    ap.add_argument("--loop", action="store_true", help="a file: play it again at its end")
    ap.add_argument("--as-fast-as-possible", action="store_true",
                    help="a file: do not wait for each picture's time")
    ap.add_argument("--jpeg-quality", type=int, default=90,
                    help="sources decoded here (neither H.264/H.265 nor MJPEG) are sent as "
                    "JPEG of this quality (default %(default)s)")
    ap.add_argument("--read-timeout-s", type=float, default=3.0,
                    help="a live source silent this long is opened again (default %(default)s)")
    add_service_arguments(ap)
    args = ap.parse_args(argv)
    if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", args.stream):
        ap.error(f"not a stream id: {args.stream!r}")
    try:
        source = parse_source(args.source, rtsp_transport=args.rtsp_transport,
                              rtp_codec=args.rtp_codec, payload_type=args.payload_type)
    except ValueError as exc:
        ap.error(str(exc))
    if source.everywhere:
        log.warning("%s listens on every interface: any host that reaches the port can send "
                    "video into stream %r; give the address of the camera's link "
                    "(%s://ADDRESS:PORT) to keep to it", source, args.stream,
                    source.url.split(":", 1)[0])
    client, stop = connect(args, log)
    if client is None:
        return 2
    with client:
        ingest = Ingest(client, source, args.stream, realtime=not args.as_fast_as_possible,
                        loop=args.loop, jpeg_quality=args.jpeg_quality,
                        read_timeout_s=args.read_timeout_s).start()
        while not stop.wait(1.0) and ingest.alive:
            pass
        ingest.close()
        counts = dict(sorted(ingest.counts.items()))
        log.info("ingest %s: %s", args.stream, counts)
        print(f"arcf-ingest: {args.stream}: {counts}", file=sys.stderr)
    return 0 if ingest.counts["published"] or not ingest.done else 1


if __name__ == "__main__":
    raise SystemExit(main())

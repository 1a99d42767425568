"""H.264 / H.265 access units in, decoded frames out: one stateful decoder per stream.

Drone cameras send encoded video, not a picture per frame: a P-frame is a difference from the
frames before it, so every access unit must go through the same decoder, in order, and a lost
or damaged one spoils every frame until the next keyframe. :class:`StreamDecoder` keeps that
state for one stream (PyAV, which ships FFmpeg in its wheels):

* it starts at the first keyframe (IDR for H.264, IRAP for H.265) and keeps the latest
  parameter sets (SPS/PPS, and VPS for H.265), which it puts in front of a keyframe that
  comes without them after a resynchronisation;
* a gap in the stream's numbering (a unit lost on the way) or a damaged unit (the decoder
  raises, reports an error while decoding it, or reports that it concealed damage: FFmpeg
  would otherwise hand out a smeared picture) drops the decoder state and waits for the next
  keyframe (which may be the unit right after the gap: a sender that skips the rest of a
  damaged group of pictures resumes there):
  no box is ever computed on a frame decoded from a broken reference;
* every outcome is returned with a reason, for the caller to count and report;
* what it is given is bounded before FFmpeg sees it: an access unit with more than
  ``MAX_NAL_UNITS`` start codes is refused (FFmpeg keeps state per NAL unit: 2 MiB of bare
  start codes took a decoder to 1.1 GB), and a parameter set declaring more than
  ``max_pixels`` is refused by FFmpeg before a picture is allocated (cause ``oversized``);
* it remembers the units of its last two groups of pictures (from their keyframes on,
  bounded in units and bytes), so that a picture of either can be decoded again
  (:meth:`StreamDecoder.replay`): a box drawn on a picture the decoder has passed is applied
  to that very picture;
* a picture is converted to BGR only when asked for (``Decoded.pixels``), and only where
  the trackers read it (:mod:`.convert`): units decoded
  only to keep the chain intact, superseded before they are tracked, cost their decoding
  and nothing more (a 36 MP skip unit: 87 ms with its conversion).

Decoding runs single-threaded per stream (FFmpeg's frame threads would hold several frames
and make the error capture ambiguous), so its memory is one decoder's: the reference frames
of one stream (measured in docs/results-adapters.md).
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from enum import Enum
from functools import cached_property
from typing import Any, cast

import av
import av.logging
import numpy as np

from arcf.region import Region, RegionFrame

from .convert import picture_bgr, picture_bgr_region
from .nal import KEYFRAME_TYPES, PARAMETER_TYPES, nal_units

#: FFmpeg's log of a picture refused for its size (libavutil's av_image_check_size2)
_OVERSIZED = "exceeds specified max pixel count"
#: FFmpeg's log level of a decoding error (AV_LOG_ERROR)
_FFMPEG_ERROR = 16
#: FFmpeg's report that it papered over damage (AV_LOG_INFO, "concealing N DC, N AC, N MV
#: errors"): some damage raises no error at all, only this (a P-frame's residuals zeroed)
_CONCEALED = "concealing"


#: units kept undecoded at most while a decoder waits for the wanted one (a group longer than
#: that is dropped, and the next keyframe starts again)
MAX_DEFERRED_UNITS = 1000


def padded_packet(data: bytes) -> av.Packet:
    """``data`` as a packet FFmpeg may read past: its decoders read up to
    ``AV_INPUT_BUFFER_PADDING_SIZE`` bytes beyond a packet's end, and PyAV's ``Packet(bytes)``
    hands FFmpeg the bytes object itself, with nothing after it (a truncated keyframe then
    reads past the object: under AddressSanitizer, into an unmapped page). ``Packet(size)``
    allocates with FFmpeg's zeroed padding."""
    packet = av.Packet(len(data))
    memoryview(packet)[:] = data
    return packet


class Outcome(str, Enum):
    """What one access unit gave."""

    FRAME = "frame"  # a picture, decoded from an intact chain since the last keyframe
    NO_FRAME = "no_frame"  # accepted, no picture out yet (e.g. the decoder's delay)
    WAITING = "waiting_for_keyframe"  # skipped: the decoder waits for a keyframe
    RESYNC = "resync"  # a gap or a damaged unit: state dropped, waiting for a keyframe


@dataclass(frozen=True)
class Decoded:
    outcome: Outcome
    #: the decoded picture (FFmpeg's, not converted yet), for ``Outcome.FRAME``
    picture: av.VideoFrame | None = None
    #: the number of the access unit the picture was decoded from (with B-frames, an earlier
    #: unit than the one just given), for ``Outcome.FRAME``
    seq: int | None = None
    #: why, for ``WAITING`` and ``RESYNC``
    reason: str | None = None
    #: what broke, for ``RESYNC``: ``gap``, ``corrupt`` or ``oversized``
    cause: str | None = None
    #: for ``FRAME``: the chain broke just before this unit (``gap``), which is a keyframe
    #: and starts the next one (the resynchronisation is counted, the unit decoded)
    resynced: str | None = None

    @cached_property
    def image(self) -> np.ndarray | None:
        """The picture as (H, W, 3) uint8 BGR, converted on first use (None without one)."""
        return None if self.picture is None else picture_bgr(self.picture)

    def pixels(self, region: Region | None) -> np.ndarray | RegionFrame | None:
        """The picture converted where the trackers read it (:mod:`.convert`)."""
        return None if self.picture is None else picture_bgr_region(self.picture, region)


@dataclass(frozen=True)
class Unit:
    """An access unit of the group of pictures a decoder remembers."""

    seq: int
    #: the unit as decoded (a keyframe with the parameter sets put in front of it)
    data: bytes
    #: whatever the caller gave with it (the service: the unit's capture and arrival times)
    tag: Any = None


class GroupOfPictures:
    """The units since the last keyframe, and the group before it, in order: what it takes to
    decode any picture of the two again (a box drawn on the last picture before a keyframe
    comes after that keyframe). Bounded by ``max_units`` and ``max_bytes`` for the two: the
    older group goes first, and a current group longer than that is forgotten until the next
    keyframe (a replay then finds nothing)."""

    def __init__(self, max_units: int, max_bytes: int) -> None:
        self.max_units, self.max_bytes = max_units, max_bytes
        self.units: list[Unit] = []
        self.previous: list[Unit] = []
        self._bytes = 0
        self._previous_bytes = 0
        #: the group outgrew the bounds (or broke): nothing is kept until the next keyframe
        self.overflowed = True

    def start(self, unit: Unit) -> None:
        """A keyframe: a new group, the current one kept as the previous."""
        if self.overflowed:
            self.previous, self._previous_bytes = [], 0
        else:
            self.previous, self._previous_bytes = self.units, self._bytes
        self.units, self._bytes, self.overflowed = [], 0, False
        self.add(unit)

    def add(self, unit: Unit) -> None:
        if self.overflowed:
            return
        self.units.append(unit)
        self._bytes += len(unit.data)
        if self.previous and (len(self.units) + len(self.previous) > self.max_units
                              or self._bytes + self._previous_bytes > self.max_bytes):
            self.previous, self._previous_bytes = [], 0
        if len(self.units) > self.max_units or self._bytes > self.max_bytes:
            self.forget()

    def forget(self) -> None:
        self.units, self.previous, self.overflowed = [], [], True
        self._bytes = self._previous_bytes = 0

    def covers(self, seq: int) -> bool:
        """Whether the picture of unit ``seq`` can be decoded again from the kept units."""
        first = self.previous or self.units
        return bool(self.units) and first[0].seq <= seq <= self.units[-1].seq

    def since_keyframe_of(self, seq: int) -> list[Unit]:
        """The units from the keyframe of the group that holds ``seq`` to the newest."""
        if self.units and seq >= self.units[0].seq:
            return list(self.units)
        return [*self.previous, *self.units]


class StreamDecoder:
    """The decoder of one stream's access units (``codec``: ``"h264"`` or ``"hevc"``).

    ``history_units`` / ``history_bytes``: the bounds of the group of pictures kept for
    :meth:`replay` (0 units: none kept)."""

    def __init__(self, codec: str, max_pixels: int = 8_847_360, history_units: int = 0,
                 history_bytes: int = 32 << 20) -> None:
        if codec not in KEYFRAME_TYPES:
            raise ValueError(f"codec must be 'h264' or 'hevc', got {codec!r}")
        self.codec = codec
        self.max_pixels = max_pixels
        self._ctx: av.VideoCodecContext | None = None
        self._params: dict[int, bytes] = {}
        self._next_seq: int | None = None
        self.group = GroupOfPictures(history_units, history_bytes)
        #: units kept undecoded before the wanted one, from their keyframe on (``decode``)
        self._deferred: list[Unit] = []
        self._deferred_bytes = 0
        #: counts by outcome, and resynchronisations by cause
        self.counts: dict[str, int] = {}
        # decoding errors and concealment notices must reach the capture (outside it, PyAV
        # hands them to Python's logging, where the "libav" logger's level filters them)
        av.logging.set_level(av.logging.INFO)
        if logging.getLogger("libav").level == logging.NOTSET:
            logging.getLogger("libav").setLevel(logging.WARNING)

    @property
    def synchronised(self) -> bool:
        """A keyframe was decoded and nothing broke since."""
        return self._ctx is not None

    def _count(self, key: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1

    def _resync(self, cause: str, reason: str) -> Decoded:
        self._ctx = None
        self.group.forget()
        self._deferred, self._deferred_bytes = [], 0
        self._count(Outcome.RESYNC.value)
        self._count(f"resync_{cause}")
        return Decoded(Outcome.RESYNC, reason=reason, cause=cause)

    def decode(self, seq: int, data: bytes, tag: Any = None, *,
               wanted_from: int | None = None) -> Decoded:
        """Decode the access unit numbered ``seq`` of the stream (``tag``: kept with it for
        :meth:`replay`).

        ``wanted_from``: no picture before unit ``wanted_from`` is wanted (every session of
        the stream waits for that one). Until the decoder has a picture, units before it are
        only kept, from their keyframe on, and decoded with the first unit at or after it
        (``NO_FRAME`` meanwhile): a worker that receives a station's recent history decodes
        the group its picture is in, not every group before."""
        if self._ctx is None and wanted_from is not None and seq < wanted_from:
            return self._defer(seq, data, tag)
        if self._deferred:
            held, self._deferred, self._deferred_bytes = self._deferred, [], 0
            self._next_seq = held[0].seq
            for unit in held:  # the group's keyframe and its units since, in order
                self._decode(unit.seq, unit.data, unit.tag)
        return self._decode(seq, data, tag)

    def _scan(self, data: bytes) -> set[int] | Decoded:
        """The NAL unit types of an access unit (its parameter sets kept); the resync if it
        is no access unit at all."""
        try:
            units = nal_units(data, self.codec)
        except ValueError as exc:
            return self._resync("corrupt", f"not a camera's access unit: {exc}")
        if not units:
            return self._resync("corrupt", "not an Annex B access unit (no start code)")
        for kind, unit in units:
            if kind in PARAMETER_TYPES[self.codec]:
                self._params[kind] = unit
        return {kind for kind, _ in units}

    def _defer(self, seq: int, data: bytes, tag: Any) -> Decoded:
        """Keep a unit before the wanted one (see :meth:`decode`), without decoding it."""
        gap = self._next_seq is not None and seq != self._next_seq
        self._next_seq = seq + 1
        kinds = self._scan(data)
        if isinstance(kinds, Decoded):
            return kinds
        if kinds & KEYFRAME_TYPES[self.codec]:
            self._deferred, self._deferred_bytes = [], 0
        elif gap or not self._deferred:  # a broken chain, or none yet: nothing to keep
            self._deferred, self._deferred_bytes = [], 0
            self._count("deferred")
            return Decoded(Outcome.NO_FRAME)
        self._deferred.append(Unit(seq, data, tag))
        self._deferred_bytes += len(data)
        if len(self._deferred) > MAX_DEFERRED_UNITS or self._deferred_bytes > self.group.max_bytes:
            self._deferred, self._deferred_bytes = [], 0  # the next keyframe starts again
        self._count("deferred")
        return Decoded(Outcome.NO_FRAME)

    def _decode(self, seq: int, data: bytes, tag: Any) -> Decoded:
        gap = self._next_seq is not None and seq != self._next_seq
        expected, self._next_seq = self._next_seq, seq + 1
        kinds = self._scan(data)
        if isinstance(kinds, Decoded):
            return kinds
        keyframe = bool(kinds & KEYFRAME_TYPES[self.codec])
        resynced = None
        if gap and self._ctx is not None:
            if not keyframe:
                return self._resync("gap", f"access unit {seq} came after {expected}'s "
                                    "place: units were lost; waiting for a keyframe")
            # the loss ended at a keyframe: the next chain starts with this very unit
            self._resync("gap", "units were lost before a keyframe")
            resynced = "gap"
        if self._ctx is None and not keyframe:
            self._count(Outcome.WAITING.value)
            return Decoded(Outcome.WAITING, reason="waiting for a keyframe")
        whole = data  # a keyframe with the parameter sets it came without: decodable alone
        if keyframe and (self._ctx is None or self.group.max_units > 0):
            whole = b"".join(u for k, u in sorted(self._params.items())
                             if k not in kinds) + data
        if self._ctx is None:
            data = whole  # a new chain: the decoder has no parameter sets of its own yet
            self._ctx = cast(av.VideoCodecContext, av.CodecContext.create(self.codec, "r"))
            self._ctx.thread_type = "NONE"
            # FFmpeg refuses a larger picture before allocating it: a parameter set declaring
            # a huge size (a decoding bomb) costs nothing
            self._ctx.options = {"max_pixels": str(self.max_pixels)}
        if self.group.max_units > 0:  # kept decodable on its own, for a replay
            if keyframe:
                self.group.start(Unit(seq, whole, tag))
            else:
                self.group.add(Unit(seq, data, tag))
        failed: Exception | None = None
        frames: list[av.VideoFrame] = []
        with av.logging.Capture(local=False) as logs:
            try:
                packet = padded_packet(data)
                packet.pts = seq  # comes back on the picture: which unit it is
                frames = self._ctx.decode(packet)
            except (av.FFmpegError, ValueError) as exc:
                failed = exc
        oversized = [text for _, _, text in logs if _OVERSIZED in text]
        if oversized:  # refused by FFmpeg before it allocated the picture
            size = re.search(r"(\d+)x(\d+)", oversized[0])
            declared = f"{size[1]}x{size[2]} pictures" if size else "larger pictures"
            return self._resync("oversized", f"the stream declares {declared}, above "
                                f"max_pixels ({self.max_pixels} pixels)")
        if failed is not None:
            return self._resync("corrupt", f"damaged access unit: {failed}")
        errors = [text.strip() for level, _, text in logs
                  if level <= _FFMPEG_ERROR or text.startswith(_CONCEALED)]
        if errors:
            return self._resync("corrupt", f"damaged access unit: {errors[0]}")
        if not frames:
            self._count(Outcome.NO_FRAME.value)
            return Decoded(Outcome.NO_FRAME)
        frame = frames[-1]
        if frame.width * frame.height > self.max_pixels:
            return self._resync("oversized", f"{frame.width}x{frame.height} pictures exceed "
                                f"{self.max_pixels} pixels")
        self._count(Outcome.FRAME.value)
        return Decoded(Outcome.FRAME, picture=frame,
                       seq=seq if frame.pts is None else int(frame.pts), resynced=resynced)

    def replay(self, first: int, last: int) -> Iterator[tuple[Decoded, Any]]:
        """The pictures of units ``first`` to ``last`` decoded again from the kept group (a
        decoder of their own: this one's state is untouched), each with its unit's tag.
        Nothing if the group does not hold ``first``; it stops at the first picture that
        does not decode cleanly (none of its successors could be trusted)."""
        if not self.group.covers(first):
            return
        units = [u for u in self.group.since_keyframe_of(first) if u.seq <= last]
        tags = {u.seq: u.tag for u in units}
        again = StreamDecoder(self.codec, self.max_pixels)
        for unit in units:
            out = again.decode(unit.seq, unit.data)
            if out.outcome in (Outcome.WAITING, Outcome.RESYNC):
                return
            if out.outcome is Outcome.FRAME and out.seq is not None and first <= out.seq <= last:
                yield out, tags.get(out.seq)


class PictureSize:
    """The picture size of a stream of access units, for stations that convert boxes
    without decoding the stream (the MAVLink camera, which needs it only when a command
    comes).

    :meth:`feed` keeps the latest parameter sets and keyframe (a scan for start codes, no
    decoding); :meth:`read` decodes that keyframe once per set of parameter sets, with the
    same ``max_pixels`` bound as :class:`StreamDecoder`, and remembers the answer."""

    def __init__(self, codec: str, max_pixels: int = 8_847_360) -> None:
        if codec not in KEYFRAME_TYPES:
            raise ValueError(f"codec must be 'h264' or 'hevc', got {codec!r}")
        self.codec, self.max_pixels = codec, max_pixels
        self._lock = threading.Lock()  # fed by a subscriber's thread, read by another
        self._params: dict[int, bytes] = {}
        self._keyframe: bytes | None = None
        self._known: tuple[tuple[bytes, ...], tuple[int, int] | None] | None = None

    def feed(self, data: bytes) -> None:
        try:
            units = nal_units(data, self.codec)
        except ValueError:
            return
        with self._lock:
            for kind, unit in units:
                if kind in PARAMETER_TYPES[self.codec]:
                    self._params[kind] = unit
            if any(kind in KEYFRAME_TYPES[self.codec] for kind, _ in units):
                self._keyframe = data

    def read(self) -> tuple[int, int] | None:
        """(width, height), or None before a keyframe and its parameter sets came, or when
        they do not decode within ``max_pixels``."""
        with self._lock:
            keyframe, key = self._keyframe, tuple(u for _, u in sorted(self._params.items()))
        if keyframe is None or not key:
            return None
        if self._known is not None and self._known[0] == key:
            return self._known[1]
        size = None
        ctx = cast(av.VideoCodecContext, av.CodecContext.create(self.codec, "r"))
        ctx.thread_type = "NONE"
        ctx.options = {"max_pixels": str(self.max_pixels)}
        with av.logging.Capture(local=True):  # a broken keyframe says so by giving nothing
            try:
                frames = ctx.decode(padded_packet(b"".join(key) + keyframe))
                frames += ctx.decode(None)
                if frames:
                    size = (frames[0].width, frames[0].height)
            except (av.FFmpegError, ValueError):
                size = None
        self._known = (key, size)
        return size

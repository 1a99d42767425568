"""What the launcher knows when a worker process dies: why, on which stream's frame, and
whether that stream has now crashed workers often enough to be refused.

A worker marks the stream whose frame it is working on (:class:`InFlight`, a few bytes of
shared memory the launcher can still read after the worker is gone) and clears the mark when
the frame is done. A worker killed by a signal (a segmentation fault in a decoder, the kernel's
out-of-memory killer, an operator's ``kill -9``) leaves the mark of the frame that was being
processed: that stream gets a strike (:class:`Strikes`). ``quarantine_after`` strikes within
``quarantine_s`` quarantine the stream: its sessions end instead of resuming, and new starts on
it are refused, for ``quarantine_s``. A death between frames (nothing marked) strikes nobody.
"""

from __future__ import annotations

import signal
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

#: bytes of a stream id in the mark (the wire contract's ids are at most 64 characters)
MARK_BYTES = 128
#: streams whose strikes are remembered at once (the oldest go first)
MAX_TRACKED_STREAMS = 4096


def death_cause(exitcode: int | None) -> str:
    """A short label for a process's end: ``SIGSEGV``, ``SIGKILL`` (also the kernel's
    out-of-memory killer), ``exit 1``..."""
    if exitcode is None:
        return "unknown"
    if exitcode < 0:
        try:
            return signal.Signals(-exitcode).name
        except ValueError:
            return f"signal {-exitcode}"
    return f"exit {exitcode}"


class InFlight:
    """The stream a worker is processing a frame of, in shared memory (``multiprocessing``'s
    unlocked ``Array``: one writer, and one reader after the writer is dead)."""

    def __init__(self, ctx: Any) -> None:
        self._buf = ctx.Array("c", MARK_BYTES, lock=False)

    def set(self, stream_id: str) -> None:
        raw = stream_id.encode()[:MARK_BYTES - 1]
        self._buf[:len(raw) + 1] = raw + b"\0"

    def clear(self) -> None:
        self._buf[0] = b"\0"

    def read(self) -> str | None:
        raw = bytes(self._buf[:]).split(b"\0", 1)[0]
        return raw.decode(errors="replace") or None


class Strikes:
    """Crashes attributed to each stream, and the streams quarantined for them."""

    def __init__(self, quarantine_after: int, quarantine_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.after = quarantine_after
        self.window_s = quarantine_s
        self.clock = clock
        self._strikes: OrderedDict[str, list[float]] = OrderedDict()
        self._until: OrderedDict[str, float] = OrderedDict()

    def strike(self, stream_id: str) -> bool:
        """Count a crash on ``stream_id``; True when it is quarantined by it."""
        now = self.clock()
        recent = [t for t in self._strikes.pop(stream_id, []) if now - t < self.window_s]
        recent.append(now)
        self._strikes[stream_id] = recent
        while len(self._strikes) > MAX_TRACKED_STREAMS:
            self._strikes.popitem(last=False)
        if self.after > 0 and len(recent) >= self.after:
            self._until.pop(stream_id, None)
            self._until[stream_id] = now + self.window_s
            while len(self._until) > MAX_TRACKED_STREAMS:
                self._until.popitem(last=False)
            return True
        return False

    def quarantined(self, stream_id: str) -> float:
        """Seconds the stream stays quarantined (0: it is not)."""
        until = self._until.get(stream_id)
        if until is None:
            return 0.0
        left = until - self.clock()
        if left <= 0:
            del self._until[stream_id]
            self._strikes.pop(stream_id, None)
            return 0.0
        return left

    def count(self, stream_id: str) -> int:
        """Crashes on the stream within the window."""
        now = self.clock()
        return sum(1 for t in self._strikes.get(stream_id, []) if now - t < self.window_s)

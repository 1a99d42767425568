"""What a stream's frames must pass before a worker spends anything on them: the per-stream rate
limit and the frame numbering. Both are pure logic here (no Zenoh, no clock of their own), so
that every rule is tested on its own; the worker applies them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum


class TokenBucket:
    """``rate`` frames per second, bursts of one second's worth: a station flooding its stream
    is refused the excess at intake, before the frame queue would hide it by dropping."""

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self.tokens = rate
        self.refilled: float | None = None

    def take(self, now: float) -> bool:
        """Whether a frame arriving at ``now`` (monotonic s) is within the rate."""
        if self.refilled is not None:
            self.tokens = min(self.rate, self.tokens + (now - self.refilled) * self.rate)
        self.refilled = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class Verdict(str, Enum):
    """What a frame's number means for its stream."""

    FIRST = "first"  #: the stream's first frame
    NEXT = "next"  #: after the last one, within ``max_gap`` (the gap: frames lost on the way)
    STALE = "stale"  #: not after the last one (duplicate, reordered): refused
    JUMP = "jump"  #: more than ``max_gap`` ahead: refused, unless confirmed (see RESTART)
    RESTART = "restart"  #: ``confirm`` frames in a row agree on a new numbering: adopted

    @property
    def accepted(self) -> bool:
        return self in (Verdict.FIRST, Verdict.NEXT, Verdict.RESTART)


@dataclass
class Numbering:
    """A stream's frame numbering, which no single frame can hijack.

    A frame numbered after the last one and at most ``max_gap`` ahead is the next frame (the
    frames between were lost on the way and are counted as such). Any other number is refused:
    behind the last one it is stale, beyond ``max_gap`` it is a jump. But a station may restart
    its numbering (a rebooted camera starts at 0) or resume after a long outage: when
    ``confirm`` refused frames in a row form an increasing run (each within ``max_gap`` of
    the one before), the stream follows the new numbering from the last of them, and no frame
    is counted as lost for the switch. One rogue frame (a wildcard put with ``seq`` 10^12, a
    replayed old frame) is refused and forgotten at the stream's next genuine frame.
    """

    max_gap: int
    confirm: int
    last: int | None = None
    run: list[int] = field(default_factory=list)

    def admit(self, seq: int) -> tuple[Verdict, int]:
        """The verdict on frame ``seq`` and how many frames it says were lost before it."""
        if self.last is None:
            self.last = seq
            return Verdict.FIRST, 0
        if self.last < seq <= self.last + self.max_gap:
            lost = seq - self.last - 1
            self.last, self.run = seq, []
            return Verdict.NEXT, lost
        if self.run and self.run[-1] < seq <= self.run[-1] + self.max_gap:
            self.run.append(seq)
        else:
            self.run = [seq]
        if len(self.run) >= self.confirm:
            self.last, self.run = seq, []
            return Verdict.RESTART, 0
        return (Verdict.STALE if seq <= self.last else Verdict.JUMP), 0

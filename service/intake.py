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
        self.capacity = max(rate, 1.0)  # below 1 frame/s, still one frame at a time
        self.tokens = self.capacity
        self.refilled: float | None = None

    def take(self, now: float) -> bool:
        """Whether a frame arriving at ``now`` (monotonic s) is within the rate."""
        if self.refilled is not None:
            self.tokens = min(self.capacity, self.tokens + (now - self.refilled) * self.rate)
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
    """A stream's frame numbering, which no single frame, and no trickle of frames, can take
    over.

    A frame numbered after the last one is the next frame if its gap is plausible: at most
    ``max_gap``, and at most what ``rate`` frames per second (the stream's rate limit) could
    have sent since the last frame, plus ``slack`` (the frames between were lost on the way and
    are counted as such). Any other number is refused: behind the last one it is stale, beyond
    the plausible gap a jump. A refused frame joins the candidate run it follows (or starts
    one): when a run reaches ``confirm`` frames, the stream follows its numbering, and no frame
    is counted as lost for the switch (a rebooted camera starting at 0, a station resuming
    after an outage). Several runs are kept apart, so frames of another numbering interleaved
    with a station's own cannot keep resetting its run; when there are too many, the one with
    the fewest frames goes. One rogue frame (a wildcard put numbered 10^12, a replayed old
    frame) is refused and forgotten at the stream's next genuine frame.
    """

    max_gap: int
    confirm: int
    rate: float = 60.0
    slack: int = 30
    max_runs: int = 4
    last: int | None = None
    last_time: float = 0.0
    #: candidate runs of refused frames: [their last frame, how many]
    runs: list[list[int]] = field(default_factory=list)

    def plausible_gap(self, now: float) -> int:
        """How far after the last frame a frame arriving at ``now`` may be numbered."""
        return min(self.max_gap, self.slack + int(self.rate * max(now - self.last_time, 0.0)))

    def admit(self, seq: int, now: float) -> tuple[Verdict, int]:
        """The verdict on frame ``seq`` arriving at ``now`` (monotonic s) and how many frames
        it says were lost before it."""
        if self.last is None:
            self.last, self.last_time = seq, now
            return Verdict.FIRST, 0
        if self.last < seq <= self.last + self.plausible_gap(now):
            lost = seq - self.last - 1
            self.last, self.last_time, self.runs = seq, now, []
            return Verdict.NEXT, lost
        for run in self.runs:
            if run[0] < seq <= run[0] + self.max_gap:
                run[0], run[1] = seq, run[1] + 1
                break
        else:
            run = [seq, 1]
            self.runs.append(run)
            if len(self.runs) > self.max_runs:
                self.runs.remove(min(self.runs[:-1], key=lambda r: r[1]))
        if run[1] >= self.confirm:
            self.last, self.last_time, self.runs = seq, now, []
            return Verdict.RESTART, 0
        return (Verdict.STALE if seq <= self.last else Verdict.JUMP), 0

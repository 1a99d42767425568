"""The results ledger: every frame a simulated station sent and every result it received, per
stream, and everything the tools read from them.

Times are ``time.monotonic()`` seconds on the station's side; latency is end to end, from the
frame's capture timestamp (set when it was published) to the result's arrival.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np


def meets_capacity(results: int, lost: int, p99_ms: float, bound_ms: float = 100.0) -> bool:
    """The capacity criterion, the one definition every tool uses: some results, not one
    frame lost (dropped by the service or never answered), p99 end-to-end latency under the
    bound."""
    return results > 0 and lost == 0 and p99_ms < bound_ms


def percentiles(seconds: list[float]) -> dict[str, float]:
    """p50 / p95 / p99 / max of latencies given in seconds, in milliseconds."""
    if not seconds:
        return {k: float("nan") for k in ("p50", "p95", "p99", "max")}
    a = np.asarray(seconds) * 1e3
    return {"p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95)),
            "p99": float(np.percentile(a, 99)), "max": float(a.max())}


@dataclass(frozen=True)
class Received:
    """One result as the station received it."""

    result: Any  #: the wire contract's Result
    t: float  #: arrival, monotonic seconds
    latency_s: float  #: capture timestamp to arrival

    @property
    def session_id(self) -> str:
        return self.result.session_id

    @property
    def frame_seq(self) -> int:
        return self.result.frame_seq

    @property
    def dropped(self) -> int:
        return self.result.dropped

    @property
    def status(self) -> str:
        return getattr(self.result.status, "value", str(self.result.status))


@dataclass
class StreamRecord:
    """What one stream sent and what its own sessions received. A stream id used again later
    (a drone that comes back) gets a new record, so that its frame numbering starts over
    cleanly; results of sessions this record does not own (another station tracking the same
    stream) are counted in ``foreign`` and otherwise ignored."""

    name: str
    cond: threading.Condition
    sessions: list[str] = field(default_factory=list)
    #: (frame seq, monotonic time sent)
    sent: list[tuple[int, float]] = field(default_factory=list)
    #: results about frames (every status but ``stopped`` and ``stale``)
    received: list[Received] = field(default_factory=list)
    #: the last ``stopped`` result of each session that ended (by its stop or the service's
    #: decision): about no frame, so apart from the frame accounting and the latencies
    ended: list[Received] = field(default_factory=list)
    #: ``stale`` notices (the stream sent no frame for the service's ``stale_after_s``): about
    #: no frame either, kept apart the same way (a paused replay gets them)
    stale: list[Received] = field(default_factory=list)
    foreign: int = 0
    _answers: dict[int, int] = field(default_factory=dict)

    def add_session(self, session_id: str) -> None:
        with self.cond:
            self.sessions.append(session_id)

    def on_sent(self, seq: int) -> None:
        with self.cond:
            self.sent.append((seq, time.monotonic()))

    def on_result(self, result: Any) -> Received | None:
        """The callback for the client's result subscription: the result as recorded (None
        if it belongs to a session of someone else)."""
        now, wall = time.monotonic(), time.time_ns()
        with self.cond:
            if result.session_id not in self.sessions:
                self.foreign += 1
                return None
            got = Received(result, now, (wall - result.capture_ts_ns) / 1e9)
            if got.status in ("stopped", "stale"):
                (self.ended if got.status == "stopped" else self.stale).append(got)
                self.cond.notify_all()
                return got
            self.received.append(got)
            self._answers[result.frame_seq] = self._answers.get(result.frame_seq, 0) + 1
            self.cond.notify_all()
        return got

    def answered(self, seq: int) -> int:
        """How many results frame ``seq`` got so far."""
        with self.cond:
            return self._answers.get(seq, 0)

    def wait(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Wait until ``predicate()`` (evaluated under the record's lock) holds, at most
        ``timeout`` s; whether it does. :meth:`wake` makes it look again."""
        with self.cond:
            return self.cond.wait_for(predicate, max(timeout, 0.0))

    def wake(self) -> None:
        with self.cond:
            self.cond.notify_all()

    def results_of(self, session_id: str) -> list[Received]:
        with self.cond:
            return [r for r in self.received if r.session_id == session_id]

    def gaps(self, t0: float, t1: float) -> int:
        """Frames with no result among those whose results arrived between t0 and t1."""
        with self.cond:
            seqs = sorted({r.frame_seq for r in self.received if t0 <= r.t <= t1})
        return sum(b - a - 1 for a, b in itertools.pairwise(seqs))

    def first_with_status(self, status: str, after: float) -> Received | None:
        with self.cond:
            hits = [r for r in self.received if r.status == status and r.t > after]
        return min(hits, key=lambda r: r.t) if hits else None

    def handover(self, after: float) -> tuple[int, float]:
        """At a handover between instances: (frames with no result, ms without a result)
        between the result before the first ``resumed`` one after ``after`` and that one."""
        first = self.first_with_status("resumed", after)
        if first is None:
            raise ValueError(f"{self.name}: no resumed result after {after}")
        with self.cond:
            before = [r for r in self.received if r.frame_seq < first.frame_seq]
        last = max(before, key=lambda r: r.frame_seq) if before else None
        if last is None:
            return first.frame_seq, 0.0
        return first.frame_seq - last.frame_seq - 1, 1e3 * (first.t - last.t)

    def accounting(self) -> dict[str, int]:
        """Every frame of every session of this stream accounted for.

        Per session, each frame up to the highest one answered either has a result or is
        counted in a later result's ``dropped`` (frames before the session's first result
        are counted here as skipped at the start); ``unaccounted`` is what neither explains.
        Frames sent after the highest answered one were still queued when the stream stopped
        (the tail); a session that never answered has every frame in its tail. Frames sent
        after the session's last result (``stopped``: the service ended it) arrived are
        ``after_end``, not tail: nobody was tracking them. Results must arrive in frame order
        (``out_of_order`` counts those that did not)."""
        out = dict.fromkeys(ACCOUNTS, 0)
        with self.cond:
            sent = list(self.sent)
            sessions = list(self.sessions)
            received = list(self.received)
            ended = {r.session_id: r.t for r in self.ended}
        for sid in sessions:
            rows = [r for r in received if r.session_id == sid]
            out["sessions"] += 1
            late = sum(1 for _, t in sent if t > ended[sid]) if sid in ended else 0
            out["after_end"] += late
            n_sent = len(sent) - late
            if not rows:
                out["tail"] += n_sent
                continue
            seqs = [r.frame_seq for r in rows]
            out["out_of_order"] += sum(1 for a, b in itertools.pairwise(seqs) if b <= a)
            first, highest = min(seqs), max(seqs)
            dropped = sum(r.dropped for r in rows) - min(rows, key=lambda r: r.frame_seq).dropped
            out["results"] += len(rows)
            out["dropped"] += dropped
            out["skipped_at_start"] += first
            out["unaccounted"] += abs(highest + 1 - first - dropped - len(rows))
            out["tail"] += max(n_sent - (highest + 1), 0)
        return out


#: the keys of an accounting, in report order
ACCOUNTS = ("sessions", "results", "dropped", "skipped_at_start", "unaccounted", "out_of_order",
            "tail", "after_end")


class Ledger:
    """The records of every stream of a run, in the order they were opened."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.records: list[StreamRecord] = []

    def open(self, name: str) -> StreamRecord:
        record = StreamRecord(name, self.cond)
        with self.cond:
            self.records.append(record)
        return record

    def __getitem__(self, name: str) -> StreamRecord:
        """The latest record of stream ``name``."""
        for record in reversed(self.records):
            if record.name == name:
                return record
        raise KeyError(name)

    def first_resumed(self, names: list[str], after: float, timeout: float) -> dict[str, float]:
        """Arrival time of each stream's first ``resumed`` result after ``after`` (waits up to
        ``timeout`` s for all of ``names``; the ones never resumed are missing from the
        answer)."""
        deadline = time.monotonic() + timeout
        found: dict[str, float] = {}
        while time.monotonic() < deadline and len(found) < len(names):
            for n in names:
                hit = self[n].first_with_status("resumed", after)
                if hit is not None:
                    found[n] = hit.t
            time.sleep(0.02)
        return found

    def after_move(self, moved: list[str], others: list[str], t0: float, timeout: float,
                   settle_s: float = 1.5, gaps_from: float | None = None) -> dict[str, Any]:
        """After an event at ``t0`` that moves the streams ``moved`` to another instance (a
        kill, a freeze, a join): how many resumed, how fast, what each lost at its handover,
        and the gaps on the other streams from ``gaps_from`` (default ``t0``; a second earlier
        for an instance that died, whose last frames may already have been lost) to
        ``settle_s`` after the last resumption."""
        found = self.first_resumed(moved, t0, timeout=timeout)
        time.sleep(settle_s)
        start = t0 if gaps_from is None else gaps_from
        return {"streams_moved": len(moved), "resumed": len(found),
                "failover_ms": [1e3 * (found[n] - t0) for n in moved if n in found],
                "handovers": [self[n].handover(t0) for n in moved if n in found],
                "other_streams_gaps": sum(self[n].gaps(start, time.monotonic())
                                          for n in others)}

    def window(self, t0: float, t1: float, records: list[StreamRecord] | None = None
               ) -> dict[str, Any]:
        """What happened between t0 and t1: frames offered, results, frames the service
        reported dropped (``dropped`` of the results received), latency."""
        chosen = self.records if records is None else records
        with self.cond:
            sent = sum(1 for rec in chosen for _, t in rec.sent if t0 <= t <= t1)
            got = [r for rec in chosen for r in rec.received if t0 <= r.t <= t1]
        sessions = (max(float(np.mean([len(rec.sessions) for rec in chosen])), 1.0)
                    if chosen else 1.0)
        dropped = sum(r.dropped for r in got)
        span = max(t1 - t0, 1e-9)
        return {"seconds": span, "offered_fps": sent / span,
                "processed_fps": len(got) / sessions / span,
                "results": len(got), "dropped": dropped,
                "drop_fraction": dropped / max(dropped + len(got), 1),
                "errors": sum(1 for r in got if r.status == "error"),
                "latency_ms": percentiles([r.latency_s for r in got]),
                "track_ms": float(np.nanmean([r.result.track_s for r in got]) * 1e3)
                if got else float("nan"),
                "scale": float(np.nanmedian([r.result.scale for r in got]))
                if got else float("nan")}

    def live_between(self, t0: float, t1: float) -> list[StreamRecord]:
        """The streams that sent frames both before t1 and after t0."""
        with self.cond:
            return [rec for rec in self.records
                    if rec.sent and rec.sent[0][1] <= t1 and rec.sent[-1][1] >= t0]

    def accounting(self) -> dict[str, int]:
        """:meth:`StreamRecord.accounting` summed over every stream of the run."""
        out = dict.fromkeys(ACCOUNTS, 0)
        for rec in self.records:
            for key, n in rec.accounting().items():
                out[key] += n
        return out

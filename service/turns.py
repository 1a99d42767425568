"""Fair turns between a worker's streams, and the budget that sheds what breaks them.

The worker serves its streams in turns: one frame of each per round (a video stream's queued
backlog decoded within ``DECODE_TURN_S``). What one turn of a stream costs (its decoding and
its sessions' tracking) is what every other stream waits. Once a second, with the window's
busy share, :class:`TurnBudget` decides whether a stream's turns starve the others for long
enough that its costliest sessions must end; the worker ends them, saying why.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from .streams import Session, Stream

#: The most a video stream's backlog may decode in one turn, seconds: the other streams of the
#: worker wait at most this (plus one unit) for a stream that fell behind.
DECODE_TURN_S = 0.05
#: Over ``worker_budget``, a stream counts as starved when one of its frames waited in its
#: queue longer than this, seconds (a frame period at 10 fps), or its queue dropped one.
STARVED_WAIT_S = 0.1
#: Consecutive one-second windows over budget, with a stream starved, before a session is
#: shed (a burst, e.g. a session's first frames, is not an overload).
OVER_BUDGET_WINDOWS = 2
#: The costliest stream is shed only if it costs this many times a starved stream: among
#: equals (more streams of the same kind than the worker can serve) none is to blame, and
#: each keeps its newest frames, dropping the rest (counted), as before.
UNFAIR = 2.0


@dataclass(frozen=True)
class Shed:
    """A session to end: why (its last result's message) and what cost too much
    (``decoding`` or ``tracking``, the metric's cause)."""

    session: Session
    why: str
    cause: str


class TurnBudget:
    """The per-worker budget ``worker_budget`` (a share of one core, 0: none)."""

    def __init__(self, budget: float) -> None:
        self.budget = budget
        #: consecutive one-second windows over budget with a stream starved by the same
        #: costliest stream (``over_stream``)
        self.over_budget = 0
        self.over_stream: str | None = None

    def window(self, streams: Iterable[Stream], busy: float, window_s: float) -> list[Shed]:
        """Close a one-second window: the sessions to shed, and every stream's and
        session's window counts reset. A worker busier than the budget while a stream's
        frames wait (or are dropped) for ``OVER_BUDGET_WINDOWS`` windows sheds its costliest
        stream (:meth:`shed_stream`). Costliest by what a turn of the stream costs (the wait
        it puts on every other stream), and only if that is ``UNFAIR`` times a starved
        stream's turn; a starved stream that is itself the costliest is only behind its own
        work: nothing is shed for it."""
        streams = list(streams)
        starved = set()
        for st in streams:
            trimmed = st.inbox.trimmed
            if st.window_wait_s > STARVED_WAIT_S or trimmed > st.trimmed_before:
                starved.add(st.stream_id)
            st.trimmed_before, st.window_wait_s = trimmed, 0.0
        # what one turn of each stream costs the others: its decoding and its sessions'
        # tracking, per frame it was served
        turn = {st.stream_id: (st.window_decode_s + sum(x.window_cpu_s
                                                        for x in st.sessions.values()))
                / max(st.window_turns, 1) for st in streams}
        heaviest = max(turn, key=turn.__getitem__, default=None)
        victims = [turn[sid] for sid in starved if sid != heaviest]
        if (self.budget and busy > self.budget and heaviest is not None and victims
                and turn[heaviest] > UNFAIR * min(victims)):
            # the same stream to blame window after window: one window's noise (a frame
            # that cost more, a preemption) never sheds anything
            same = heaviest == self.over_stream
            self.over_budget = self.over_budget + 1 if same else 1
            self.over_stream = heaviest
        else:
            self.over_budget, self.over_stream = 0, None
        shed: list[Shed] = []
        if self.over_budget >= OVER_BUDGET_WINDOWS and heaviest is not None:
            # once shed, one more window over budget sheds again (the load is known to be real)
            self.over_budget = OVER_BUDGET_WINDOWS - 1
            stream = next(st for st in streams if st.stream_id == heaviest)
            shed = self.shed_stream(stream, UNFAIR * min(victims), busy, window_s)
        for st in streams:
            st.window_decode_s, st.window_turns = 0.0, 0
            for x in st.sessions.values():
                x.window_cpu_s = 0.0
        return shed

    def shed_stream(self, stream: Stream, fair_turn_s: float, busy: float,
                    window_s: float) -> list[Shed]:
        """What makes ``stream``'s turn cost more than ``fair_turn_s``: every session when
        decoding it costs more than any one session's tracking; else its sessions, costliest
        first, until what is left of its turn fits (so a stream of twelve heavy sessions is
        brought down in one go, not one a window)."""
        turns = max(stream.window_turns, 1)
        sessions = sorted(stream.sessions.values(), key=lambda x: x.window_cpu_s, reverse=True)
        share = (f"the most on a worker {100 * busy:.0f} % busy, over worker_budget "
                 f"{100 * self.budget:g} %, while other streams waited")
        if stream.window_decode_s > sessions[0].window_cpu_s:
            why = (f"session ended: decoding stream {stream.stream_id!r} took "
                   f"{1e3 * stream.window_decode_s / window_s:.0f} ms of CPU a second "
                   f"({1e3 * stream.window_decode_s / turns:.0f} ms a turn), {share}")
            return [Shed(s, why, "decoding") for s in sessions]
        out = []
        turn_s = (stream.window_decode_s + sum(s.window_cpu_s for s in sessions)) / turns
        for s in sessions:
            if turn_s <= fair_turn_s:
                break
            turn_s -= s.window_cpu_s / turns
            out.append(Shed(s, f"session ended: its tracking took "
                               f"{1e3 * s.window_cpu_s / window_s:.0f} ms of CPU a second, on "
                               f"stream {stream.stream_id!r}, {share}", "tracking"))
        return out

"""Where a stream runs within one instance: placed, and moved, by what its frames cost.

A stream's frames are decoded once and every session of the stream tracks them on one
worker, so a stream is the unit of placement. What a stream costs depends on the target far
more than on the picture (a large target fills ARCF-HC's window; a lost track searches), so
counting streams leaves one worker with twice the other's load. Each worker reports, once a
second, the CPU each of its streams used (its decoding and its sessions' tracking, in cores);
:class:`LoadBook` smooths these into a cost per stream, and:

* :meth:`LoadBook.place` puts a new stream on the worker with the least measured load (a
  stream not measured yet counts as the mean of the measured ones);
* :meth:`LoadBook.plan_move` names one stream to move from the busiest worker to the least
  busy when that lowers the busiest worker's load by at least ``min_gain`` cores and it is
  above ``busy_above``; a stream moved is left alone for ``settle_s`` (its cost measured
  afresh where it now runs), so a run of costly frames (a lost target's search) does not
  bounce a stream back and forth;
* a *spare* worker (``spare_workers``) takes no new stream, and a move goes to one only when
  the busiest worker is ``overloaded`` (near a whole core: it drops frames) and no move among
  the others helps. Streams are whole: three of 0.55 cores on two workers leave one with 1.1
  cores whatever the placement, while three processes on two cores share them (0.67 each).
  Light streams stay on as many workers as cores, where the kernel never has to time-slice
  them.

Pure logic, no clock of its own and no processes: tested on its own
(tests/service/test_placement.py); the control plane does the moving.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from .cluster import weight

__all__ = ["LoadBook", "Move", "StreamLoad", "place"]


@dataclass(frozen=True)
class StreamLoad:
    """What a worker reports of one of its streams each second."""

    #: CPU seconds its frames took per second of the report's window (cores)
    cores: float
    #: whether the stream can move to another worker without losing its sessions' state
    #: (frames, not a video stream whose decoder would have to wait for a keyframe; trackers
    #: whose state can be handed over)
    movable: bool


@dataclass(frozen=True)
class Move:
    stream_id: str
    source: int
    target: int
    #: the busiest worker's load before and after, cores
    before: float
    after: float


def place(stream_id: str, loads: Sequence[float], counts: Sequence[int] | None = None) -> int:
    """The worker for a new stream: the least loaded (``loads``, cores), then the one with the
    fewest streams (``counts``), ties broken by rendezvous rank so the choice is
    deterministic."""
    workers = range(len(loads))
    rank = {w: i for i, w in enumerate(sorted(workers, key=lambda w: -weight(stream_id, w)))}
    n = counts if counts is not None else [0] * len(loads)
    return min(workers, key=lambda w: (round(loads[w], 3), n[w], rank[w]))


@dataclass
class _Cost:
    cores: float
    movable: bool
    #: monotonic time until which the stream is not moved again
    settled_at: float = 0.0


@dataclass
class LoadBook:
    """Each stream's smoothed cost, from the workers' reports. Where each stream runs is the
    caller's (``where``: stream -> worker, from its session records), so that a stream
    placed but not reported yet counts at once, and one that ended counts no more."""

    #: weight of a new report in the smoothed cost (about the last 1 / alpha seconds)
    alpha: float = 0.3
    min_gain: float = 0.1
    busy_above: float = 0.5
    settle_s: float = 10.0
    #: a worker's load (cores) from which a spare may take one of its streams
    overloaded: float = 0.9
    costs: dict[str, _Cost] = field(default_factory=dict)

    def report(self, streams: dict[str, StreamLoad]) -> None:
        """A worker's report of its streams."""
        for sid, load in streams.items():
            known = self.costs.get(sid)
            if known is None:
                self.costs[sid] = _Cost(load.cores, load.movable)
            else:
                known.cores += self.alpha * (load.cores - known.cores)
                known.movable = load.movable

    def loads(self, where: dict[str, int], workers: int,
              excluded: Iterable[int] = ()) -> list[float]:
        """Cores per worker, a stream without a report yet counted as the measured mean;
        ``excluded`` workers (not taking streams) as infinitely loaded. Streams no longer in
        ``where`` are forgotten."""
        for sid in [s for s in self.costs if s not in where]:
            del self.costs[sid]
        measured = [c.cores for c in self.costs.values()]
        guess = sum(measured) / len(measured) if measured else 0.0
        out = [0.0] * workers
        for sid, w in where.items():
            if 0 <= w < workers:
                cost = self.costs.get(sid)
                out[w] += cost.cores if cost is not None else guess
        for w in excluded:
            out[w] = float("inf")
        return out

    def place(self, stream_id: str, where: dict[str, int], workers: int,
              excluded: Iterable[int] = ()) -> int:
        """The worker for a new stream (:func:`place` on the measured loads)."""
        counts = [0] * workers
        for w in where.values():
            if 0 <= w < workers:
                counts[w] += 1
        return place(stream_id, self.loads(where, workers, excluded), counts)

    def plan_move(self, where: dict[str, int], workers: int, now: float,
                  excluded: Iterable[int] = (), spares: Iterable[int] = ()) -> Move | None:
        """The one move that best lowers the busiest worker's load, if worth it (see the
        module's rules); None otherwise."""
        spares = set(spares)
        move = self._best_move(where, workers, now, {*excluded, *spares})
        if move is not None or not spares:
            return move
        move = self._best_move(where, workers, now, set(excluded))
        if move is None or move.target not in spares or move.before < self.overloaded:
            return None
        return move

    def _best_move(self, where: dict[str, int], workers: int, now: float,
                   excluded: set[int]) -> Move | None:
        """The best move from the busiest of the workers not ``excluded`` to another."""
        loads = self.loads(where, workers)
        live = [w for w in range(workers) if w not in excluded]
        if len(live) < 2:
            return None
        source = max(live, key=lambda w: loads[w])
        if loads[source] <= self.busy_above:
            return None
        best: Move | None = None
        for sid, w in sorted(where.items()):
            cost = self.costs.get(sid)
            if w != source or cost is None or not cost.movable or now < cost.settled_at:
                continue
            for target in live:
                if target == source:
                    continue
                after = max(loads[source] - cost.cores, loads[target] + cost.cores,
                            *(loads[o] for o in live if o not in (source, target)))
                if after <= loads[source] - self.min_gain and (best is None or after < best.after):
                    best = Move(sid, source, target, loads[source], after)
        return best

    def moved(self, stream_id: str, now: float) -> None:
        """A stream moved: it settles where it now runs before it may move again."""
        cost = self.costs.get(stream_id)
        if cost is not None:
            cost.settled_at = now + self.settle_s

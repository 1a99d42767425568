"""Placement within one instance by measured cost (:mod:`arcf.service.placement`): where new
streams go, which stream moves and when none does; and a stream's state handed from one
worker's parts to another's, bit for bit (:mod:`arcf.service.handoff`)."""

from __future__ import annotations

import pickle
from typing import Any

import cv2
import pytest

from arcf.schemas import Result, decode
from arcf.service import metrics
from arcf.service.handoff import StreamState, movable, pack
from arcf.service.intake import Numbering
from arcf.service.placement import LoadBook, StreamLoad, place
from arcf.service.stages import StageClock
from arcf.service.streams import Picture, Session, Stream


def _book(**costs: float) -> LoadBook:
    book = LoadBook()
    book.report({sid: StreamLoad(c, True) for sid, c in costs.items()})
    return book


def test_new_streams_go_where_the_measured_load_is_least() -> None:
    # counted, the workers are even (two streams each); measured, worker 0 carries 1.1 cores
    book = _book(a=0.6, b=0.5, c=0.2, d=0.2)
    where = {"a": 0, "b": 0, "c": 1, "d": 1}
    assert book.loads(where, 2) == pytest.approx([1.1, 0.4])
    assert book.place("e", where, 2) == 1
    # a stream placed but not reported yet counts as the measured mean (0.375)
    where["e"] = 1
    assert book.loads(where, 2) == pytest.approx([1.1, 0.775])
    # a worker that takes no streams (a replacement starting) is chosen last
    assert book.place("f", where, 2, excluded={1}) == 0
    # streams that ended are forgotten
    book.loads({"a": 0}, 2)
    assert set(book.costs) == {"a"}
    # on idle workers: the fewest streams, then the rendezvous rank (deterministic)
    assert place("x", [0.0, 0.0], [1, 0]) == 1
    assert place("x", [0.0, 0.0, 0.0]) == place("x", [0.0, 0.0, 0.0])


def test_the_move_that_best_lowers_the_busiest_worker_is_chosen() -> None:
    book = _book(a=0.5, b=0.5, c=0.5, d=0.1)
    where = {"a": 0, "b": 0, "c": 0, "d": 1}
    move = book.plan_move(where, 2, now=100.0)
    assert move is not None and (move.source, move.target) == (0, 1)
    assert move.stream_id == "a"  # equals: the first by name, a deterministic choice
    assert (move.before, move.after) == pytest.approx((1.5, 1.0))
    book.moved(move.stream_id, now=100.0)
    where["a"] = 1
    # settled: not moved again for settle_s, even should its worker become the busiest
    assert book.plan_move({"a": 1, "b": 0, "d": 1}, 2, now=101.0) is None


def test_a_spare_worker_takes_a_stream_only_off_an_overloaded_worker() -> None:
    """Two workers and a spare (2): three heavy streams leave one worker with two whatever
    the placement, and only the spare can take one; light ones never go to the spare."""
    book = _book(a=0.48, b=0.48, c=0.55)  # a and b saturate worker 0 (0.96 cores)
    where = {"a": 0, "b": 0, "c": 1}
    assert book.place("new", where, 3, excluded={2}) in (0, 1)  # never the spare
    move = book.plan_move(where, 3, now=100.0, spares={2})
    assert move is not None and (move.source, move.target) == (0, 2)
    assert move.after == pytest.approx(0.55)
    # light: worker 0 busy (0.6) but far from a core, so its frames do not wait; no spare
    light = _book(a=0.3, b=0.3, c=0.3)
    assert light.plan_move(where, 3, now=100.0, spares={2}) is None
    # a move among the others that helps is preferred to the spare
    uneven = _book(a=0.5, b=0.45, c=0.1)
    move = uneven.plan_move(where, 3, now=100.0, spares={2})
    assert move is not None and move.target == 1


def test_no_move_for_a_small_gain_an_idle_pool_or_a_stream_that_cannot_move() -> None:
    # 0.55 against 0.5: moving the 0.05 stream gains less than min_gain
    book = _book(a=0.5, b=0.05, c=0.5)
    assert book.plan_move({"a": 0, "b": 0, "c": 1}, 2, now=0.0) is None
    # the busiest worker is below busy_above: nothing waits there
    book = _book(a=0.2, b=0.2)
    assert book.plan_move({"a": 0, "b": 0}, 2, now=0.0) is None
    # the only stream worth moving is a video stream (not movable)
    book = LoadBook()
    book.report({"v": StreamLoad(0.6, False), "w": StreamLoad(0.6, True)})
    assert book.plan_move({"v": 0, "w": 0}, 2, now=0.0) is not None  # w may move
    assert book.plan_move({"v": 0, "w": 1, "x": 1}, 2, now=0.0) is None  # v alone may not
    # one live worker: nowhere to go
    assert _book(a=0.9, b=0.9).plan_move({"a": 0, "b": 0}, 2, now=0.0,
                                         excluded={1}) is None


def test_a_moved_cost_is_smoothed_not_replaced() -> None:
    book = _book(a=0.4)
    book.report({"a": StreamLoad(1.4, True)})  # one costly second (a lost target's search)
    assert book.costs["a"].cores == pytest.approx(0.4 + book.alpha * 1.0)


class _Results:
    def __init__(self) -> None:
        self.sent: list[Result] = []

    def put(self, data: bytes) -> None:
        self.sent.append(decode(data, expected=Result))


def _stream() -> Stream:
    return Stream("cam", None, None, None, Numbering(300, 3, rate=60.0))  # type: ignore[arg-type]


def test_a_stream_handed_over_gives_the_results_it_would_have_given(
        wakeboard7: Any) -> None:
    """Half of wakeboard7 on one stream, then its state packed and carried to another
    process's stream (as a move does between workers), and the rest: every result equals an
    unmoved stream's."""
    from arcf import create_tracker
    from arcf.service.tracking import Tracking

    box = tuple(wakeboard7.groundtruth[0])
    frames = [cv2.imread(str(p)) for p in wakeboard7.frames[:30]]
    runs = []
    for move_at in (None, 12):
        stream = _stream()
        stream.sessions["s"] = Session("s", "cam", "arcf-h",
                                       create_tracker("arcf-h", **{"state.reacquire": True}),
                                       _Results(), pending_box=box)
        tracking = Tracking(metrics, StageClock(metrics.STAGE_CPU), session_budget_s=10.0)
        sent: list[Result] = []
        for seq, image in enumerate(frames):
            if seq == move_at:
                assert movable(stream)
                sent += stream.sessions["s"].publisher.sent
                # as the queues between the instance's processes carry it
                state = pickle.loads(pickle.dumps(pack(stream)))
                assert isinstance(state, StreamState)
                stream = _stream()
                stream.numbering = state.numbering
                (st,) = state.sessions
                stream.sessions["s"] = st.session("cam", _Results())
                assert (stream.sessions["s"].frames, stream.sessions["s"].last_seq) == (12, 11)
            assert tracking.run(stream, Picture(seq, seq, seq, 0.0, image)) == []
        runs.append(sent + stream.sessions["s"].publisher.sent)
    still, moved = runs
    assert len(moved) == len(still) == 30
    assert [(r.frame_seq, r.box, r.track_state, r.confidence, r.dropped) for r in moved] == [
        (r.frame_seq, r.box, r.track_state, r.confidence, r.dropped) for r in still]


def test_streams_whose_state_cannot_move_say_so() -> None:
    class Unpicklable:
        initialized = True

        def __reduce__(self) -> Any:
            raise TypeError("cannot pickle a network")

    stream = _stream()
    stream.sessions["s"] = Session("s", "cam", "nanotrack", Unpicklable(), None)
    assert not movable(stream)
    stream = _stream()
    stream.decoder = object()  # type: ignore[assignment]  # a video stream
    assert not movable(stream)

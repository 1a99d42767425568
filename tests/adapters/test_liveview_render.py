"""Which picture the live view renders and what it draws on it: each session's box on the
frame the box belongs to, a session that ended or fell far behind never freezes the view, and
a session whose stream stopped is drawn again, marked stale, until frames resume."""

from __future__ import annotations

from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from arcf.adapters.liveview import STALE_BGR, Watch, colour_bgr, draw
from arcf.adapters.tap import TapFrame
from arcf.schemas import Result, ResultStatus


class _Sub:
    def close(self) -> None:
        pass

    undeclare = close


class FakeClient:
    """Just what a stream tap asks of a client: it keeps the callbacks to call them."""

    def __init__(self) -> None:
        self.callbacks: dict[str, Any] = {}
        self.session = SimpleNamespace(declare_subscriber=self._declare)

    def _declare(self, key: str, callback: Any) -> _Sub:
        self.callbacks["video"] = callback
        return _Sub()

    def frames(self, stream_id: str, callback: Any) -> _Sub:
        self.callbacks["frames"] = callback
        return _Sub()

    def results(self, stream_id: str, callback: Any) -> _Sub:
        self.callbacks["results"] = callback
        return _Sub()


def result(session: str, seq: int, status: str = "tracking",
           box: tuple[float, ...] = (11, 21, 40, 30)) -> Result:
    return Result(session_id=session, stream_id="cam", frame_seq=seq, capture_ts_ns=1,
                  box=list(box), peak=0.5, psr=10.0, aberrance=0.01, aberrance_release=0.01,
                  scale=1.0, status=status, dropped=0, received_ts_ns=1, decode_s=0.0,
                  track_s=0.0, published_ts_ns=1, confidence=0.9, track_state="tracking")


def stale(session: str, seq: int) -> Result:
    """The service's notice: no frame for stale_after_s (no box, no track state)."""
    nan = float("nan")
    return Result(session_id=session, stream_id="cam", frame_seq=seq, capture_ts_ns=1,
                  box=[nan] * 4, peak=nan, psr=nan, aberrance=nan, aberrance_release=nan,
                  scale=nan, status="stale", code="no_frames", message="no frame for 1.0 s",
                  dropped=0, received_ts_ns=1, decode_s=0.0, track_s=0.0, published_ts_ns=1)


@pytest.fixture
def watched() -> Iterator[tuple[Watch, Any]]:
    """A stream's render state (no renderer running), and its frame callback; closed after."""
    w = Watch(FakeClient(), "cam", max_fps=0.001, max_width=960, video_key=None)  # type: ignore[arg-type]
    try:
        yield w, w._on_frame
    finally:
        w.close()


def frame(seq: int) -> TapFrame:
    return TapFrame("cam", seq, 1, "jpeg", b"jpeg")


def test_the_newest_frame_every_session_answered_is_rendered_with_its_boxes(
    watched: tuple[Watch, Any],
) -> None:
    w, on_frame = watched
    for k in range(5):
        on_frame(frame(k))
    w._on_result(result("a", 3))
    w._on_result(result("b", 2))
    seq, _, drawn = w._pick()
    assert seq == 2
    assert {r.session_id: r.frame_seq for _, r in drawn} == {"b": 2}  # a's 3 is later
    w._on_result(result("a", 2))
    seq, _, drawn = w._pick()
    assert {r.session_id: r.frame_seq for _, r in drawn} == {"a": 2, "b": 2}


def test_an_ended_or_stale_session_does_not_freeze_the_view(watched: tuple[Watch, Any]) -> None:
    w, on_frame = watched
    for k in range(3):
        on_frame(frame(k))
    w._on_result(result("a", 2))
    w._on_result(result("b", 1))
    assert w._pick()[0] == 1
    w._on_result(result("b", 1, status="stopped"))  # b ended
    assert w._pick()[0] == 2
    w._on_result(result("c", 0))  # c answers frame 0 only and falls behind
    for k in range(3, 20):
        on_frame(frame(k))
    w._on_result(result("a", 19))
    assert w._pick()[0] == 19  # frame 0 is long gone: c no longer holds it back


def test_boxes_are_drawn_in_the_sessions_colour_where_the_result_says() -> None:
    picture = np.zeros((100, 200, 3), np.uint8)
    out = draw(picture, [(0, result("a", 0, box=(11, 21, 40, 30)))], scale=1.0)
    # 1-based (11, 21) is pixel (10, 20): the edges run there, in the session's colour
    assert tuple(out[20, 30]) == colour_bgr(0) and tuple(out[35, 10]) == colour_bgr(0)
    assert tuple(out[50, 30]) == colour_bgr(0) and tuple(out[35, 50]) == colour_bgr(0)
    assert tuple(out[35, 30]) == (0, 0, 0)  # inside: untouched


def test_a_stale_session_is_drawn_again_marked_until_a_frame_comes(
    watched: tuple[Watch, Any],
) -> None:
    w, on_frame = watched
    for k in range(3):
        on_frame(frame(k))
    w._on_result(result("a", 2))
    w._on_result(result("b", 2))
    seq, _, drawn = w._pick()
    w.rendered_key = seq  # rendered
    assert w._pick() is None  # nothing new: no frame, no change
    w._on_result(stale("a", 2))  # a's stream stopped: the same frame, drawn again
    seq, _, drawn = w._pick()
    w.rendered_key = seq
    by = {r.session_id: r for _, r in drawn}
    assert seq == 2 and by["a"].status == "stale" and by["a"].box == (11, 21, 40, 30)
    assert by["a"].message == "no frame for 1.0 s" and by["b"].status == "tracking"
    w._on_result(stale("a", 2))  # the notice repeated: nothing to draw again
    assert w._pick() is None
    on_frame(frame(3))  # frames again: a's next result is about a frame, not stale
    w._on_result(result("a", 3))
    w._on_result(result("b", 3))
    seq, _, drawn = w._pick()
    assert seq == 3 and all(r.status == "tracking" for _, r in drawn)


def test_a_stale_box_is_grey_and_thin_not_the_sessions_colour() -> None:
    picture = np.zeros((100, 200, 3), np.uint8)
    marked = result("a", 0, box=(11, 21, 40, 30)).model_copy(
        update={"status": ResultStatus.STALE})
    out = draw(picture, [(0, marked)], scale=1.0)
    assert tuple(out[35, 10]) == STALE_BGR and tuple(out[35, 50]) == STALE_BGR  # its edges
    assert tuple(out[35, 11]) == (0, 0, 0)  # one pixel wide
    assert not (out == np.array(colour_bgr(0), np.uint8)).all(axis=2).any()


def test_on_the_video_key_results_meet_their_pictures_by_capture_time(
    watched: tuple[Watch, Any],
) -> None:
    """Opened mid-stream: the view numbers the video key's units from its subscription, the
    service from its own (here 57 units earlier); the timestamp names the same picture."""
    w, on_frame = watched
    for k in range(5):
        on_frame(TapFrame("cam", k, 1000 * (k + 1), "jpeg", b"jpeg", source="compressed_video"))
    for k in range(4):  # the service's numbers for the first four pictures
        w._on_result(result("a", 57 + k).model_copy(update={"capture_ts_ns": 1000 * (k + 1)}))
    key, _, drawn = w._pick()
    assert key == 4000 and [(r.frame_seq, r.capture_ts_ns) for _, r in drawn] == [(60, 4000)]
    w.rendered_key = key
    w._on_result(result("a", 61).model_copy(update={"capture_ts_ns": 5000}))
    key, _, drawn = w._pick()
    assert key == 5000 and [r.frame_seq for _, r in drawn] == [61]


def test_a_restarted_numbering_is_followed(watched: tuple[Watch, Any]) -> None:
    w, on_frame = watched
    for k in range(100, 105):
        on_frame(frame(k))
    w._on_result(result("a", 104))
    assert w._pick()[0] == 104
    for k in range(3):  # the camera restarted from 0
        on_frame(frame(k))
    w._on_result(result("a", 2))
    key, _, drawn = w._pick()
    assert key == 2 and [r.frame_seq for _, r in drawn] == [2]

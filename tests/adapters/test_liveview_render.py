"""Which picture the live view renders and what it draws on it: each session's box on the
frame the box belongs to, a session that ended or fell far behind never freezes the view, and
a session whose stream stopped is drawn again, marked stale, until frames resume."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
import pytest

from arcf.adapters.liveview import STALE_BGR, Watch, colour_bgr, draw
from arcf.adapters.tap import TapFrame
from arcf.schemas import Result, ResultStatus


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
def view(offline_client: Any) -> Iterator[Watch]:
    """A stream's render state (no renderer running; frames in by its ``_on_frame``), closed
    after. The client is the adapters' offline stand-in: a stream tap only keeps callbacks."""
    w = Watch(offline_client, "cam", max_fps=0.001, max_width=960, video_key=None)
    try:
        yield w
    finally:
        w.close()


def frame(seq: int) -> TapFrame:
    return TapFrame("cam", seq, 1, "jpeg", b"jpeg")


def feed(w: Watch, frames: Iterable[int], *answers: tuple[str, int]) -> None:
    """The ``frames`` arrive, then each answer: session ``name``'s tracking result about the
    frame numbered ``seq`` (the order every test here plays a stream in)."""
    for k in frames:
        w._on_frame(frame(k))
    for name, seq in answers:
        w._on_result(result(name, seq))


def test_the_newest_frame_every_session_answered_is_rendered_with_its_boxes(view: Watch) -> None:
    feed(view, range(5), ("a", 3), ("b", 2))
    seq, _, drawn = view._pick()
    assert seq == 2
    assert {r.session_id: r.frame_seq for _, r in drawn} == {"b": 2}  # a's 3 is later
    view._on_result(result("a", 2))
    seq, _, drawn = view._pick()
    assert {r.session_id: r.frame_seq for _, r in drawn} == {"a": 2, "b": 2}


def test_an_ended_or_stale_session_does_not_freeze_the_view(view: Watch) -> None:
    feed(view, range(3), ("a", 2), ("b", 1))
    assert view._pick()[0] == 1
    view._on_result(result("b", 1, status="stopped"))  # b ended
    assert view._pick()[0] == 2
    view._on_result(result("c", 0))  # c answers frame 0 only and falls behind
    feed(view, range(3, 20))
    view._on_result(result("a", 19))
    assert view._pick()[0] == 19  # frame 0 is long gone: c no longer holds it back


def test_boxes_are_drawn_in_the_sessions_colour_where_the_result_says() -> None:
    picture = np.zeros((100, 200, 3), np.uint8)
    out = draw(picture, [(0, result("a", 0, box=(11, 21, 40, 30)))], scale=1.0)
    # 1-based (11, 21) is pixel (10, 20): the edges run there, in the session's colour
    assert tuple(out[20, 30]) == colour_bgr(0) and tuple(out[35, 10]) == colour_bgr(0)
    assert tuple(out[50, 30]) == colour_bgr(0) and tuple(out[35, 50]) == colour_bgr(0)
    assert tuple(out[35, 30]) == (0, 0, 0)  # inside: untouched


def test_a_stale_session_is_drawn_again_marked_until_a_frame_comes(view: Watch) -> None:
    feed(view, range(3), ("a", 2), ("b", 2))
    seq, _, drawn = view._pick()
    view.rendered_key = seq  # rendered
    assert view._pick() is None  # nothing new: no frame, no change
    view._on_result(stale("a", 2))  # a's stream stopped: the same frame, drawn again
    seq, _, drawn = view._pick()
    view.rendered_key = seq
    by = {r.session_id: r for _, r in drawn}
    assert seq == 2 and by["a"].status == "stale" and by["a"].box == (11, 21, 40, 30)
    assert by["a"].message == "no frame for 1.0 s" and by["b"].status == "tracking"
    view._on_result(stale("a", 2))  # the notice repeated: nothing to draw again
    assert view._pick() is None
    # frames again: a's next result is about a frame, not stale
    feed(view, [3], ("a", 3), ("b", 3))
    seq, _, drawn = view._pick()
    assert seq == 3 and all(r.status == "tracking" for _, r in drawn)


def test_a_stale_box_is_grey_and_thin_not_the_sessions_colour() -> None:
    picture = np.zeros((100, 200, 3), np.uint8)
    marked = result("a", 0, box=(11, 21, 40, 30)).model_copy(
        update={"status": ResultStatus.STALE})
    out = draw(picture, [(0, marked)], scale=1.0)
    assert tuple(out[35, 10]) == STALE_BGR and tuple(out[35, 50]) == STALE_BGR  # its edges
    assert tuple(out[35, 11]) == (0, 0, 0)  # one pixel wide
    assert not (out == np.array(colour_bgr(0), np.uint8)).all(axis=2).any()


def test_on_the_video_key_results_meet_their_pictures_by_capture_time(view: Watch) -> None:
    """Opened mid-stream: the view numbers the video key's units from its subscription, the
    service from its own (here 57 units earlier); the timestamp names the same picture."""
    for k in range(5):
        view._on_frame(TapFrame("cam", k, 1000 * (k + 1), "jpeg", b"jpeg",
                                source="compressed_video"))
    for k in range(4):  # the service's numbers for the first four pictures
        view._on_result(result("a", 57 + k).model_copy(
            update={"capture_ts_ns": 1000 * (k + 1)}))
    key, _, drawn = view._pick()
    assert key == 4000 and [(r.frame_seq, r.capture_ts_ns) for _, r in drawn] == [(60, 4000)]
    view.rendered_key = key
    view._on_result(result("a", 61).model_copy(update={"capture_ts_ns": 5000}))
    key, _, drawn = view._pick()
    assert key == 5000 and [r.frame_seq for _, r in drawn] == [61]


def test_a_restarted_numbering_is_followed(view: Watch) -> None:
    feed(view, range(100, 105), ("a", 104))
    assert view._pick()[0] == 104
    feed(view, range(3), ("a", 2))  # the camera restarted from 0
    key, _, drawn = view._pick()
    assert key == 2 and [r.frame_seq for _, r in drawn] == [2]

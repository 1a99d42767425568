"""A stream that stops: a real service on loopback, real JPEG frames. Its sessions say so
with a ``stale`` result (no box, code ``no_frames``), repeated while it lasts, before any idle
expiry; when frames resume, results about them resume and the notices stop; the idle expiry
still ends a session whose frames never come back, with its usual code.

What is asserted is what arrives and in which order, never how fast: the "within a second"
is the ``stale_after_s`` setting (0.8 s by default), measured by
``benchmarks/stale_stream.py``."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import pytest

pytest.importorskip("zenoh")

from arcf.client import TrackingClient
from arcf.data import data_root
from arcf.loadtools.driver import Clip
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import Arrivals

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]


@pytest.fixture(scope="module")
def service() -> Iterator[ServiceProcess]:
    """Stale after 0.8 s (the default), sessions idle for 5 s end: room for a few notices
    before the expiry."""
    svc = ServiceProcess("--session-idle-s", "5", workers=1)
    yield svc
    assert svc.stop() == 0


@pytest.fixture(scope="module")
def clip(wakeboard7: Any) -> Clip:
    return Clip.of(wakeboard7, limit=20)


class Results(Arrivals[Any]):
    """Every result of a stream, in arrival order, with a wait for a condition on them."""

    def __init__(self, client: TrackingClient, stream: str) -> None:
        super().__init__(describe=lambda r: (r.frame_seq, r.status.value))
        self._sub = client.results(stream, callback=self)

    def close(self) -> None:
        self._sub.close()


def statuses(results: list[Any], *wanted: str) -> list[Any]:
    return [r for r in results if r.status.value in wanted]


def send(client: TrackingClient, results: Results, clip: Clip, stream: str,
         seqs: range) -> None:
    """Frames ``seqs`` in lock-step: each one once the previous one has its result."""
    for seq in seqs:
        client.publish_frame(stream, data=clip.frames[seq % len(clip)], seq=seq)
        results.wait(lambda got, seq=seq: any(r.frame_seq == seq and r.track_state
                                              for r in got), f"result of frame {seq}")


def assert_stale_notice(r: Any, last_seq: int) -> None:
    """A ``stale`` result's content: about the session's last frame, no box, a reason."""
    assert r.status.value == "stale" and r.code.value == "no_frames"
    assert r.frame_seq == last_seq and r.dropped == 0
    assert all(math.isnan(v) for v in (*r.box, r.peak, r.psr, r.aberrance, r.scale))
    assert r.track_state is None and r.confidence is None and r.reacquired is None
    assert "no frame of stream" in (r.message or "")


def test_a_stream_that_stops_is_stale_until_its_frames_resume(service, clip) -> None:
    stale_before = service.metric("arcf_sessions_stale_total")
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        results = Results(client, "pause")
        ack = client.start("pause", clip.box, preset="bacf", frame_seq=0)
        send(client, results, clip, "pause", range(0, 8))

        # the frames stop: a stale notice about frame 7, then again while it lasts
        got = results.wait(lambda got: len(statuses(got, "stale")) >= 2, "two stale notices")
        first, again = statuses(got, "stale")[:2]
        assert first.session_id == ack.session_id
        assert_stale_notice(first, 7)
        assert_stale_notice(again, 7)
        assert "the box of frame 7 is not current" in first.message
        assert again.published_ts_ns > first.published_ts_ns
        assert got.index(first) > max(i for i, r in enumerate(got) if r.frame_seq == 7
                                      and r.track_state)  # after the last frame's result
        assert statuses(got, "stopped") == []  # the session goes on
        assert [s.session_id for s in client.status(stream_id="pause").sessions] == [
            ack.session_id]

        # frames again: results about them, tracking from where it was, nothing lost
        seen = len(got)
        send(client, results, clip, "pause", range(8, 13))
        resumed = [r for r in results.got[seen:] if r.track_state]
        assert [r.frame_seq for r in resumed] == list(range(8, 13))
        assert all(r.status.value == "tracking" and r.dropped == 0 for r in resumed)
        assert all(math.isfinite(v) for v in resumed[0].box)
        # one episode counted, however many notices
        assert service.metric("arcf_sessions_stale_total") - stale_before == 1

        # they stop for good: stale again, then the idle expiry ends the session as before
        got = results.wait(lambda got: statuses(got, "stopped"), "idle expiry")
        after = got[got.index(resumed[-1]) + 1:]
        (stopped,) = statuses(after, "stopped")
        notices = statuses(after, "stale")
        assert notices and after.index(notices[-1]) < after.index(stopped)
        assert all(r.frame_seq == 12 for r in notices)
        assert stopped.code.value == "session_expired" and "no frame" in stopped.message
        assert service.metric("arcf_sessions_stale_total") - stale_before == 2
        results.close()


def test_a_session_whose_first_frame_does_not_come_says_so(service, clip) -> None:
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        results = Results(client, "never")
        ack = client.start("never", clip.box, preset="bacf")
        got = results.wait(lambda got: statuses(got, "stale"), "stale notice")
        (notice, *_) = statuses(got, "stale")
        assert_stale_notice(notice, 0)  # no frame yet: frame 0, as a stopped result says
        assert "since the session started" in notice.message
        # its frame comes after all: the box applies to it, as before
        client.publish_frame("never", data=clip.frames[0], seq=0)
        got = results.wait(lambda got: statuses(got, "initialized"), "initialized result")
        (first,) = statuses(got, "initialized")
        assert first.frame_seq == 0 and first.session_id == ack.session_id
        client.stop(ack.session_id)
        got = results.wait(lambda got: statuses(got, "stopped"), "stopped result")
        assert statuses(got, "stopped")[0].code is None  # the station's stop
        results.close()


def test_stale_after_s_0_turns_the_notices_off(clip) -> None:
    with ServiceProcess("--stale-after-s", "0", "--session-idle-s", "2", workers=1) as svc, \
            TrackingClient(connect=[svc.endpoint], frame_congestion="block") as client:
        results = Results(client, "quiet")
        client.start("quiet", clip.box, preset="bacf", frame_seq=0)
        send(client, results, clip, "quiet", range(0, 3))
        got = results.wait(lambda got: statuses(got, "stopped"), "idle expiry")
        assert statuses(got, "stale") == []  # silence until the idle expiry, as before
        assert statuses(got, "stopped")[0].code.value == "session_expired"
        assert svc.metric("arcf_sessions_stale_total") == 0
        results.close()

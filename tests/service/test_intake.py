"""The intake rules on their own: the per-stream rate limit and the frame numbering that no
single frame can take over."""

from __future__ import annotations

import pytest

from service.intake import Numbering, TokenBucket, Verdict


def test_the_rate_limit_allows_a_second_of_burst_then_the_rate() -> None:
    bucket = TokenBucket(10.0)
    assert sum(bucket.take(0.0) for _ in range(25)) == 10  # a burst: one second's worth
    assert not bucket.take(0.05)  # half a token refilled
    assert bucket.take(0.1)  # one token
    steady = TokenBucket(10.0)
    took = [steady.take(k / 20) for k in range(200)]  # 20 fps offered for 10 s
    assert sum(took[:20]) >= 18  # the first second: the rate plus the burst
    assert sum(took[100:]) == pytest.approx(50, abs=1)  # then 10 fps: every other frame


def _feed(numbering: Numbering, seqs: list[int]) -> list[tuple[str, int]]:
    return [(v.value, lost) for v, lost in map(numbering.admit, seqs)]


def test_gaps_within_the_bound_are_frames_lost() -> None:
    n = Numbering(max_gap=100, confirm=3)
    assert _feed(n, [5, 6, 9, 109]) == [("first", 0), ("next", 0), ("next", 2), ("next", 99)]


def test_one_rogue_frame_cannot_lock_a_stream_out() -> None:
    n = Numbering(max_gap=100, confirm=3)
    assert _feed(n, [0, 1, 10**12, 2, 3]) == [
        ("first", 0), ("next", 0), ("jump", 0), ("next", 0), ("next", 0)]
    assert _feed(n, [1, 4]) == [("stale", 0), ("next", 0)]  # a replayed old frame
    assert n.last == 4 and n.run == []


def test_rogue_frames_interleaved_with_the_real_stream_never_win() -> None:
    n = Numbering(max_gap=100, confirm=3)
    n.admit(0)
    for k in range(1, 50):  # an attacker's frame between every genuine one
        assert n.admit(10**9 + k)[0] is Verdict.JUMP
        assert n.admit(k) == (Verdict.NEXT, 0)


def test_a_restarted_numbering_is_followed_after_confirmation() -> None:
    n = Numbering(max_gap=100, confirm=3)
    _feed(n, [500, 501])
    # the camera reboots and counts from 0 again: two frames refused, then followed
    assert _feed(n, [0, 1, 2, 3]) == [("stale", 0), ("stale", 0), ("restart", 0), ("next", 0)]
    # a long outage: the station resumes far ahead; nothing counted as lost for the switch
    assert _feed(n, [90_000, 90_001, 90_003, 90_004]) == [
        ("jump", 0), ("jump", 0), ("restart", 0), ("next", 0)]


def test_duplicates_never_confirm_a_restart() -> None:
    n = Numbering(max_gap=100, confirm=3)
    _feed(n, [10, 11])
    assert _feed(n, [3, 3, 3, 3]) == [("stale", 0)] * 4
    assert _feed(n, [12]) == [("next", 0)]

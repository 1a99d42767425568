"""The intake rules on their own: the per-stream rate limit and the frame numbering that no
single frame can take over."""

from __future__ import annotations

import pytest

from arcf.service.intake import Numbering, TokenBucket


def test_the_rate_limit_allows_a_second_of_burst_then_the_rate() -> None:
    bucket = TokenBucket(10.0)
    assert sum(bucket.take(0.0) for _ in range(25)) == 10  # a burst: one second's worth
    assert not bucket.take(0.05)  # half a token refilled
    assert bucket.take(0.1)  # one token
    steady = TokenBucket(10.0)
    took = [steady.take(k / 20) for k in range(200)]  # 20 fps offered for 10 s
    assert sum(took[:20]) >= 18  # the first second: the rate plus the burst
    assert sum(took[100:]) == pytest.approx(50, abs=1)  # then 10 fps: every other frame


def _feed(numbering: Numbering, seqs: list[int], dt: float = 1.0) -> list[tuple[str, int]]:
    """Feed frames ``dt`` s apart (a whole second by default: every gap up to 90 plausible)."""
    out = []
    for seq in seqs:
        numbering.clock += dt
        verdict, lost = numbering.admit(seq, numbering.clock)
        out.append((verdict.value, lost))
    return out


class _Clocked(Numbering):
    clock: float = 0.0


def test_gaps_within_the_bound_are_frames_lost() -> None:
    n = _Clocked(max_gap=100, confirm=3)
    assert _feed(n, [5, 6, 9, 109], dt=2.0) == [
        ("first", 0), ("next", 0), ("next", 2), ("next", 99)]
    # but only as many as the stream's rate could have sent since: 60/s here, plus 30
    fast = _Clocked(max_gap=900, confirm=3)
    assert _feed(fast, [0, 1, 899], dt=0.033) == [("first", 0), ("next", 0), ("jump", 0)]
    assert _feed(fast, [2, 40], dt=0.033) == [("next", 0), ("jump", 0)]
    assert _feed(fast, [500], dt=8.0) == [("next", 497)]  # 8 s of loss: plausible
    # the bound a refusal names: the rate's, until max_seq_gap caps it
    assert fast.plausible_gap(fast.last_time + 1.0) == 30 + 60
    assert fast.plausible_gap(fast.last_time + 60.0) == 900


def test_one_rogue_frame_cannot_lock_a_stream_out() -> None:
    n = _Clocked(max_gap=100, confirm=3)
    assert _feed(n, [0, 1, 10**12, 2, 3]) == [
        ("first", 0), ("next", 0), ("jump", 0), ("next", 0), ("next", 0)]
    assert _feed(n, [1, 4]) == [("stale", 0), ("next", 0)]  # a replayed old frame
    assert n.last == 4 and n.runs == []


def test_rogue_frames_interleaved_with_the_real_stream_never_win() -> None:
    n = _Clocked(max_gap=100, confirm=3)
    _feed(n, [0])
    for k in range(1, 50):  # an attacker's frame between every genuine one
        assert _feed(n, [10**9 + 7 * k]) == [("jump", 0)]
        assert _feed(n, [k]) == [("next", 0)]


def test_a_restarted_numbering_is_followed_after_confirmation() -> None:
    n = _Clocked(max_gap=100, confirm=3)
    _feed(n, [500, 501])
    # the camera reboots and counts from 0 again: two frames refused, then followed
    assert _feed(n, [0, 1, 2, 3]) == [("stale", 0), ("stale", 0), ("restart", 0), ("next", 0)]
    # a long outage: the station resumes far ahead; nothing counted as lost for the switch
    assert _feed(n, [90_000, 90_001, 90_003, 90_004]) == [
        ("jump", 0), ("jump", 0), ("restart", 0), ("next", 0)]


def test_duplicates_never_confirm_a_restart() -> None:
    n = _Clocked(max_gap=100, confirm=3)
    _feed(n, [10, 11])
    assert _feed(n, [3, 3, 3, 3]) == [("stale", 0)] * 4
    assert _feed(n, [12]) == [("next", 0)]


def test_a_trickle_of_foreign_numbers_cannot_keep_a_station_out() -> None:
    """An attacker takes the numbering over with three frames, then puts one frame of yet
    another numbering after every two of the station's: the station's own run is kept apart
    and wins the numbering back after three frames."""
    n = _Clocked(max_gap=100, confirm=3)
    _feed(n, [0, 1, 2])
    assert _feed(n, [10**12, 10**12 + 1, 10**12 + 2])[-1] == ("restart", 0)
    verdicts = []
    for k in range(3, 60, 2):
        verdicts += _feed(n, [k, k + 1, 10**15 + 1000 * k], dt=0.05)
    genuine = [v for i, v in enumerate(verdicts) if i % 3 != 2]
    assert genuine[:3] == [("stale", 0), ("stale", 0), ("restart", 0)]
    assert all(v == ("next", 0) for v in genuine[3:])


def test_a_far_frame_right_after_a_genuine_one_counts_no_losses() -> None:
    n = _Clocked(max_gap=900, confirm=3)
    _feed(n, [0], dt=0.0)
    assert _feed(n, [899, 1, 2], dt=0.033) == [("jump", 0), ("next", 0), ("next", 0)]

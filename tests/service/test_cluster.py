"""Scale-out pieces that need no network: ownership by rendezvous hashing, and the registry's
handling of what it receives."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from arcf.schemas import KeySpace, Result, SessionSpec, decode, encode
from arcf.service.cluster import Cluster, owner, usable_box

STREAMS = [f"cam-{k}" for k in range(3000)]


def test_removing_an_instance_moves_only_its_streams() -> None:
    before = {s: owner(s, ["a", "b", "c"]) for s in STREAMS}
    after = {s: owner(s, ["a", "c"]) for s in STREAMS}
    moved = [s for s in STREAMS if before[s] != after[s]]
    assert moved and all(before[s] == "b" for s in moved)
    assert all(after[s] == before[s] for s in STREAMS if before[s] != "b")


def test_adding_an_instance_takes_a_fair_share_and_moves_nothing_else() -> None:
    before = {s: owner(s, ["a", "b", "c"]) for s in STREAMS}
    after = {s: owner(s, ["a", "b", "c", "d"]) for s in STREAMS}
    moved = [s for s in STREAMS if before[s] != after[s]]
    assert all(after[s] == "d" for s in moved)  # only to the newcomer
    assert 0.2 < len(moved) / len(STREAMS) < 0.3  # about a quarter
    shares = [sum(v == m for v in before.values()) / len(STREAMS) for m in "abc"]
    assert max(shares) - min(shares) < 0.06  # spread evenly


def test_owner_does_not_depend_on_member_order() -> None:
    assert all(owner(s, ["x", "y", "z"]) == owner(s, ["z", "x", "y"]) for s in STREAMS[:200])


def test_usable_box() -> None:
    assert usable_box((10.0, 20.0, 30.0, 40.0))
    for bad in [(10.0, 20.0, 3.0, 0.0), (1.0, 2.0, float("nan"), 4.0), (1.0, 2.0, -3.0, 4.0),
                (1e12, 2.0, 3.0, 4.0)]:
        assert not usable_box(bad)


class _Query:
    def __init__(self) -> None:
        self.replies: list[tuple[str, bytes]] = []

    def reply(self, key: str, payload: bytes) -> None:
        self.replies.append((key, payload))


def _result(session: str, seq: int, box: tuple[float, ...], status: str = "tracking") -> Any:
    r = Result(session_id=session, stream_id="cam", frame_seq=seq, capture_ts_ns=1, box=box,
               peak=0.5, psr=9.0, aberrance=0.1, aberrance_release=0.1, scale=1.0,
               status=status, dropped=0, received_ts_ns=1, decode_s=0.0, track_s=0.0,
               published_ts_ns=1)
    return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: encode(r)))


def test_registry_keeps_the_last_usable_box_and_answers_joiners_with_it() -> None:
    cluster = Cluster(session=None, keys=KeySpace(), instance_id="a")
    spec = SessionSpec(session_id="s1", stream_id="cam", preset="arcf-h", box=(5, 5, 20, 20),
                       frame_seq=0)
    cluster.specs["s1"] = spec
    cluster._on_result(_result("s1", 3, (10.0, 10.0, 20.0, 21.0)))
    cluster._on_result(_result("s1", 4, (11.0, 10.0, 3.0, 0.0)))  # collapsed: not kept
    cluster._on_result(_result("s1", 5, (float("nan"),) * 4, status="error"))
    cluster._on_result(_result("other", 6, (1.0, 1.0, 2.0, 2.0)))  # not a known session
    assert cluster.last == {"s1": (3, (10.0, 10.0, 20.0, 21.0))}
    assert cluster.resume_point("s1") == ((10.0, 10.0, 20.0, 21.0), 4, True)

    query = _Query()
    cluster._on_registry_query(query)
    (key, payload), = query.replies
    assert key == "arcf/v1/registry/s1"
    answer = decode(payload, expected=SessionSpec)
    assert answer.last_seq == 3 and answer.last_box == (10.0, 10.0, 20.0, 21.0)

    joiner = Cluster(session=None, keys=KeySpace(), instance_id="b")
    joiner._merge(payload)
    assert joiner.resume_point("s1") == ((10.0, 10.0, 20.0, 21.0), 4, True)
    joiner._merge(b"\x93garbage")  # a malformed entry is ignored, not fatal
    assert list(joiner.specs) == ["s1"]


def test_a_session_without_results_resumes_from_its_start_box() -> None:
    cluster = Cluster(session=None, keys=KeySpace(), instance_id="a")
    cluster.specs["s2"] = SessionSpec(session_id="s2", stream_id="cam", preset="bacf",
                                      box=(5, 6, 20, 30), frame_seq=7)
    assert cluster.resume_point("s2") == ((5.0, 6.0, 20.0, 30.0), 7, False)

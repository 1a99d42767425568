"""Scale-out pieces that need no network: ownership by rendezvous hashing, and the registry's
handling of what it receives."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from arcf.schemas import KeySpace, LastBox, LastBoxes, SessionSpec, decode, encode
from arcf.service.cluster import EARLY_BOXES, Cluster, owner, usable_box

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


def _boxes(*entries: tuple[str, int, tuple[float, ...]], worker: int = 0) -> Any:
    m = LastBoxes(instance_id="a", worker=worker, boxes=[
        LastBox(session_id=sid, frame_seq=seq, box=box) for sid, seq, box in entries])
    return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: encode(m)))


def test_registry_keeps_the_last_usable_box_and_answers_joiners_with_it() -> None:
    cluster = Cluster(session=None, keys=KeySpace(), instance_id="a")
    spec = SessionSpec(session_id="s1", stream_id="cam", preset="arcf-h", box=(5, 5, 20, 20),
                       frame_seq=0)
    cluster.specs["s1"] = spec
    cluster._on_last_boxes(_boxes(("s1", 3, (10.0, 10.0, 20.0, 21.0)),
                                  ("other", 6, (1.0, 1.0, 2.0, 2.0))))  # not a known session
    cluster._on_last_boxes(_boxes(("s1", 2, (9.0, 10.0, 20.0, 21.0)), worker=1))  # older
    cluster._on_last_boxes(SimpleNamespace(payload=SimpleNamespace(
        to_bytes=lambda: b"\x93garbage")))  # malformed: ignored, not fatal
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


def test_a_box_that_overtakes_its_sessions_spec_counts() -> None:
    """A worker's first box can reach an instance before the owner's registry put does."""
    cluster = Cluster(session=None, keys=KeySpace(), instance_id="b")
    cluster._on_last_boxes(_boxes(("s3", 0, (5.0, 5.0, 20.0, 20.0))))
    assert cluster.last == {}
    spec = SessionSpec(session_id="s3", stream_id="cam", preset="bacf", box=(4, 4, 20, 20),
                       frame_seq=0)
    cluster._merge(encode(spec))
    assert cluster.resume_point("s3") == ((5.0, 5.0, 20.0, 20.0), 1, True)
    for k in range(EARLY_BOXES + 10):  # never-registered sessions: bounded
        cluster._on_last_boxes(_boxes((f"x{k}", 1, (1.0, 1.0, 2.0, 2.0))))
    assert len(cluster.early) == EARLY_BOXES


def test_a_session_without_results_resumes_from_its_start_box() -> None:
    cluster = Cluster(session=None, keys=KeySpace(), instance_id="a")
    cluster.specs["s2"] = SessionSpec(session_id="s2", stream_id="cam", preset="bacf",
                                      box=(5, 6, 20, 30), frame_seq=7)
    assert cluster.resume_point("s2") == ((5.0, 6.0, 20.0, 30.0), 7, False)


class _Registry:
    """A Zenoh session as the cluster uses it to ask the others for their registry."""

    def __init__(self, *specs: SessionSpec) -> None:
        self.specs = specs
        self.asked = 0
        self.routers = ["r1"]

    def get(self, key: str, **_: Any) -> list[Any]:
        self.asked += 1
        return [SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(
            to_bytes=lambda s=s: encode(s)))) for s in self.specs]


def _member(instance: str, put: bool) -> Any:
    import zenoh

    return SimpleNamespace(key_expr=f"arcf/v1/instances/{instance}",
                           kind=zenoh.SampleKind.PUT if put else zenoh.SampleKind.DELETE)


def _running(session: _Registry) -> tuple[Cluster, Any]:
    """A joined cluster of instances a and b, its rebalancing thread running; the event its
    rebalances set."""
    import threading

    rebalanced = threading.Event()
    cluster = Cluster(session=session, keys=KeySpace(), instance_id="a",
                      on_change=rebalanced.set, linked=lambda: bool(session.routers))
    cluster.joined, cluster.members = True, {"a", "b"}
    cluster._thread.start()
    return cluster, rebalanced


def test_an_instance_back_from_a_partition_gets_the_registry_it_missed() -> None:
    """What the other side of a partition registered (or kept, while this side ended it) is
    merged when another instance appears, before the rebalance that follows."""
    spec = SessionSpec(session_id="s9", stream_id="cam-9", preset="bacf", box=(4, 4, 20, 20),
                       frame_seq=0)
    session = _Registry(spec)
    cluster, rebalanced = _running(session)
    try:
        cluster._on_member(_member("b", put=False))  # a partition: b out of sight
        assert rebalanced.wait(10)
        assert session.asked == 0 and cluster.spec("s9") is None
        rebalanced.clear()
        cluster._on_member(_member("b", put=True))  # healed
        assert rebalanced.wait(10)
        assert session.asked == 1 and cluster.spec("s9") == spec
        assert cluster.live() == ["a", "b"]
    finally:
        cluster.close()


def test_an_instance_cut_off_from_every_router_rebalances_once_linked_again() -> None:
    session = _Registry()
    session.routers = []
    cluster, rebalanced = _running(session)
    try:
        cluster._on_member(_member("b", put=False))  # seen gone: the link was lost
        assert not rebalanced.wait(0.3)  # nothing taken over while cut off
        session.routers = ["r2"]  # linked to another router
        assert rebalanced.wait(10)
    finally:
        cluster.close()


class _Network(_Registry):
    """A Zenoh session as a starting cluster uses it; ``others``: the instances live."""

    def __init__(self, *specs: SessionSpec, others: tuple[str, ...] = ()) -> None:
        super().__init__(*specs)
        self.others = others

    def declare_subscriber(self, key: str, callback: Any) -> Any:
        return SimpleNamespace(undeclare=lambda: None)

    declare_queryable = declare_subscriber

    def liveliness(self) -> Any:
        def tokens(key: str, **_: Any) -> list[Any]:
            return [SimpleNamespace(ok=SimpleNamespace(key_expr=f"arcf/v1/instances/{o}"))
                    for o in self.others]

        return SimpleNamespace(get=tokens, declare_token=lambda key: SimpleNamespace(
            undeclare=lambda: None), declare_subscriber=lambda *a, **k: SimpleNamespace(
            undeclare=lambda: None))

    def put(self, key: str, payload: bytes) -> None:
        pass

    def delete(self, key: str) -> None:
        pass


def test_the_state_file_brings_back_a_lone_instances_sessions(tmp_path: Any) -> None:
    """What runs, each session with its last box, is on disk at exit; an instance started
    with the file resumes from there, unless other instances are live (their registry is
    the truth); a damaged line is skipped, a withdrawn session leaves the file."""
    from arcf.service.statefile import StateFile

    state = StateFile(tmp_path / "sessions.jsonl")
    spec = SessionSpec(session_id="s1", stream_id="cam", preset="bacf", box=(4, 4, 20, 20),
                       frame_seq=0, control_token_sha256="ab" * 32)
    first = Cluster(session=_Network(), keys=KeySpace(), instance_id="a", state=state)
    first.start()
    first.publish(spec)
    first.note_boxes(LastBoxes(instance_id="a", worker=0, boxes=[
        LastBox(session_id="s1", frame_seq=41, box=(9, 9, 20, 20))]))
    first.close()
    with state.path.open("a") as out:
        out.write('{"v": 1, "type": "session_spec", "session_id": "broken"}\n')

    again = Cluster(session=_Network(), keys=KeySpace(), instance_id="a2", state=state)
    again.start()
    try:
        read = again.spec("s1")
        assert read is not None and again.spec("broken") is None
        assert read.model_copy(update={"last_seq": None, "last_box": None}) == spec
        assert again.resume_point("s1") == ((9.0, 9.0, 20.0, 20.0), 42, True)
        again.withdraw("s1")
    finally:
        again.close()
    assert [s.session_id for s in state.load()] == []

    state.save([spec])
    fleet = Cluster(session=_Network(others=("b",)), keys=KeySpace(), instance_id="a3",
                    state=state)
    fleet.start()
    try:
        assert fleet.spec("s1") is None  # b's registry, not the file
    finally:
        fleet.close()

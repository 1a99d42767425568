"""Nested parameters over the wire: a session's ``overrides`` set the fields of ``state`` and
``scale_filter`` by their dotted names (``"state.reacquire": true``), as the presets reply
advertises them, from the SDK and from a station that only read the wire contract; a bad
dotted name or value gets ``invalid_parameter``. A real service on loopback, real JPEG frames
of a scene whose target vanishes and comes back far away: the session re-acquires it."""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator
from typing import Any

import msgpack
import pytest

pytest.importorskip("zenoh")

from arcf.client import ServiceError, TrackingClient
from arcf.loadtools.procs import ServiceProcess
from arcf.presets import PRESETS
from arcf.schemas import Result

pytestmark = pytest.mark.integration

PREFIX = "arcf/v1"  # the wire contract's default, spelt out as a docs-only station would
NESTED = {"state.reacquire": True, "state.probes": 3}


@pytest.fixture(scope="module")
def service() -> Iterator[ServiceProcess]:
    svc = ServiceProcess(workers=1)
    yield svc
    assert svc.stop() == 0


def _stream() -> str:
    return "nested-" + uuid.uuid4().hex[:8]


def test_every_advertised_nested_parameter_is_accepted(service: ServiceProcess) -> None:
    """What the presets reply advertises with a dotted name, a start accepts: all of them at
    once, each at the preset's own value."""
    with TrackingClient(connect=[service.endpoint]) as client:
        info = client.presets()
        values = {p.name: p.values for p in info.presets}["arcf-hc"]
        dotted = {p.name for p in info.parameters if "." in p.name}
        assert {"state.reacquire", "state.probes", "scale_filter.n_scales"} <= dotted
        ack = client.start(_stream(), (10, 10, 40, 40), preset="arcf-hc",
                           overrides={name: values[name] for name in sorted(dotted)})
        assert ack.session_id
        client.stop(ack.session_id)


def test_an_sdk_session_with_dotted_overrides_reacquires(
        service: ServiceProcess, reacquire_scenario: Any) -> None:
    """Two sessions on one stream, the same JPEG frames: the one started with
    ``{"state.reacquire": True, "state.probes": 3}`` finds the target again where it came
    back; the one started with ``{"state.reacquire": False}`` does not."""
    stream = _stream()
    results: list[Result] = []
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        sub = client.results(stream, callback=results.append)
        box = reacquire_scenario.init_box
        on = client.start(stream, box, preset="arcf-hc", overrides=dict(NESTED)).session_id
        off = client.start(stream, box, preset="arcf-hc",
                           overrides={"state.reacquire": False}).session_id

        def answered(k: int) -> bool:
            return {r.session_id for r in list(results)
                    if r.frame_seq == k and r.track_state is not None} >= {on, off}

        reacquire_scenario.replay(
            lambda k, jpeg: client.publish_frame(stream, data=jpeg, seq=k), answered)
        client.stop(on)
        client.stop(off)
        sub.close()

    def of(session: str) -> list[tuple[int, Any, bool]]:
        mine = [r for r in results if r.session_id == session and r.track_state is not None]
        assert sorted(r.frame_seq for r in mine) == list(range(reacquire_scenario.length))
        return [(r.frame_seq, r.box, bool(r.reacquired)) for r in mine]

    assert reacquire_scenario.reacquisitions(of(on)), \
        "the session with state.reacquire never re-acquired the target at its new place"
    assert not reacquire_scenario.reacquisitions(of(off))


def _control(client: TrackingClient, request: dict[str, Any]) -> dict[str, Any]:
    """A request as raw msgpack on the control key, its reply as a raw map."""
    raw = msgpack.packb({"v": 1, **request}, use_bin_type=True)
    (reply,) = list(client.session.get(f"{PREFIX}/control", payload=raw, timeout=10))
    assert reply.ok is not None
    answer = msgpack.unpackb(reply.ok.payload.to_bytes(), raw=False)
    assert isinstance(answer, dict)
    return answer


def test_a_docs_only_station_starts_a_session_with_dotted_overrides(
        service: ServiceProcess, reacquire_scenario: Any) -> None:
    """msgpack maps on the keys of docs/wire-contract.md, no SDK: ``"overrides":
    {"state.reacquire": true, "state.probes": 3}`` in ``start``, frames put by hand, results
    read as maps carrying ``"reacquired": true``."""
    stream = _stream()
    maps: list[dict[str, Any]] = []
    with TrackingClient(connect=[service.endpoint], tie_sessions=False) as client:
        zs = client.session  # just the Zenoh session
        sub = zs.declare_subscriber(
            f"{PREFIX}/streams/{stream}/sessions/*/results",
            lambda s: maps.append(msgpack.unpackb(s.payload.to_bytes(), raw=False)))
        ack = _control(client, {"type": "start", "request_id": "r-1", "stream_id": stream,
                                "box": list(reacquire_scenario.init_box), "preset": "arcf-hc",
                                "overrides": dict(NESTED)})
        assert ack["type"] == "ack", ack
        session = ack["session_id"]
        pub = zs.declare_publisher(f"{PREFIX}/streams/{stream}/frames")

        def publish(k: int, jpeg: bytes) -> None:
            pub.put(msgpack.packb({"v": 1, "type": "frame", "stream_id": stream, "seq": k,
                                   "capture_ts_ns": time.time_ns(), "encoding": "jpeg",
                                   "payload": jpeg}, use_bin_type=True))

        reacquire_scenario.replay(
            publish, lambda k: any(m.get("frame_seq") == k and m.get("track_state")
                                   for m in list(maps)))
        # with the session's control token, from the start's ack (wire contract: stop)
        stopped = _control(client, {"type": "stop", "request_id": "r-2", "session_id": session,
                                    "control_token": ack["control_token"]})
        assert stopped["type"] == "ack", stopped
        pub.undeclare()
        sub.undeclare()
    tracked = [m for m in maps if m["session_id"] == session and m.get("track_state")]
    assert sorted(m["frame_seq"] for m in tracked) == list(range(reacquire_scenario.length))
    assert reacquire_scenario.reacquisitions(
        (m["frame_seq"], m["box"], m.get("reacquired") is True) for m in tracked), \
        "no result map said reacquired at the target's new place"


@pytest.mark.parametrize(("overrides", "words"), [
    ({"state.nope": True}, "unknown state parameter(s) ['nope']"),
    ({"state.probes": 0}, "state.probes must be an integer in [1, 16], got 0"),
    ({"state.reacquire": "yes"}, "state.reacquire must be true or false"),
    ({"state.lost_below": 0.9}, "state thresholds must satisfy"),
    ({"scale_filter.n_scales": 1000}, "scale_filter.n_scales must be an integer in [1, 65]"),
    ({"foo.bar": 1}, "unknown parameter 'foo.bar'"),
    ({"state.reacquire.x": True}, "unknown parameter 'state.reacquire.x'"),
    ({"state": True}, "state must be a StateParams or a dict of its fields"),
])
def test_a_bad_nested_override_is_refused_with_invalid_parameter(
        service: ServiceProcess, overrides: dict[str, Any], words: str) -> None:
    stream = _stream()
    with TrackingClient(connect=[service.endpoint]) as client:
        with pytest.raises(ServiceError) as refused:
            client.start(stream, (10, 10, 40, 40), preset="arcf-hc",
                         overrides={"state.reacquire": True, **overrides})
        assert refused.value.code == "invalid_parameter"
        assert words in refused.value.error.message
        assert str(refused.value).startswith("invalid_parameter: ")  # as a log line shows it
        # the same request as a docs-only station sends it: the same code, as a map
        error = _control(client, {"type": "start", "request_id": "r-bad", "stream_id": stream,
                                  "box": [10, 10, 40, 40], "preset": "arcf-hc",
                                  "overrides": overrides})
        assert (error["type"], error["code"]) == ("error", "invalid_parameter"), error
        assert words in error["message"]
        # nothing started, and the service goes on
        assert all(s.stream_id != stream for s in client.status().sessions)
    assert service.proc.poll() is None


def test_the_presets_reply_values_match_the_presets(service: ServiceProcess) -> None:
    """The dotted values the reply gives are the presets' own nested fields."""
    with TrackingClient(connect=[service.endpoint]) as client:
        info = client.presets()
    for p in info.presets:
        if p.name not in PRESETS:  # a Siamese preset or the hybrid: no overrides at all
            assert p.values == {}
            continue
        preset = PRESETS[p.name]
        assert p.values["state.reacquire"] is preset.state.reacquire
        assert p.values["state.probes"] == preset.state.probes
        assert p.values["scale_filter.n_scales"] == preset.scale_filter.n_scales

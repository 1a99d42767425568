"""A hostile (or merely broken) ground station against a real service on loopback.

One victim stream is tracked at 10 fps throughout; another station then does what a buggy or
malicious one can: puts frames and garbage on wildcard key expressions, numbers a frame 10^12,
floods its own stream, sends overrides of the wrong type or far outside their range. For each
attack: the victim's frames keep being processed (every frame sent gets a result or a counted
drop, latency stays bounded), the attacker gets a documented error, and the service's counters
say what happened."""

from __future__ import annotations

import time
from typing import Any

import msgpack
import pytest

pytest.importorskip("zenoh")

from arcf.data import data_root
from arcf.eval import load_dataset
from loadtools.driver import Clip, Fleet, Pacing
from loadtools.procs import ServiceProcess
from schemas import ErrorMessage, Frame, KeySpace, decode, encode
from service.client import ServiceError, TrackingClient
from service.scrape import fetch, series

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

KEYS = KeySpace()


@pytest.fixture(scope="module")
def service():
    svc = ServiceProcess("--max-stream-fps", "30")
    yield svc
    assert svc.stop() == 0


@pytest.fixture(scope="module")
def clip() -> Clip:
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    return Clip.of(seq, limit=40)


def errors_by_kind(svc: ServiceProcess) -> dict[str, float]:
    assert svc.metrics_url is not None
    return {labels["kind"]: value
            for labels, value in series(fetch(svc.metrics_url)).get("arcf_errors_total", [])}


class Victim:
    """A well-behaved station: one stream at 10 fps, one session, its error notices."""

    def __init__(self, client: TrackingClient, clip: Clip, name: str) -> None:
        self.notices: list[ErrorMessage] = []
        self.sub = client.session.declare_subscriber(
            KEYS.errors(name), lambda s: self.notices.append(
                decode(s.payload.to_bytes(), expected=ErrorMessage)))
        self.fleet = Fleet(client, [clip], preset="bacf", pacing=Pacing.fixed_rate(10.0))
        (self.stream,) = self.fleet.add(names=[name])
        time.sleep(1.0)  # running before the attack

    def check(self, t0: float) -> dict[str, Any]:
        """Since ``t0``: every frame answered or reported dropped, latency bounded."""
        time.sleep(0.5)
        window = self.fleet.window(t0, time.monotonic())
        counts = self.stream.record.accounting()
        assert window["results"] >= 0.8 * window["offered_fps"] * window["seconds"], window
        assert window["latency_ms"]["p99"] < 500, window
        assert counts["unaccounted"] == 0 and counts["out_of_order"] == 0, counts
        assert self.notices == [], [n.code for n in self.notices]
        return window

    def close(self) -> None:
        self.fleet.close()
        self.sub.undeclare()


def test_wildcard_puts_reach_no_stream(service, clip) -> None:
    with TrackingClient(connect=[service.endpoint]) as client:
        victim = Victim(client, clip, "victim-wild")
        try:
            before = errors_by_kind(service)
            dropped_before = service.metric("arcf_frames_dropped_total")
            t0 = time.monotonic()
            rogue = encode(Frame(stream_id="victim-wild", seq=10**12, capture_ts_ns=1,
                                 encoding="jpeg", payload=clip.frames[0]))
            for key in (KEYS.all_frames(), f"{KEYS.prefix}/**", f"{KEYS.prefix}/streams/**"):
                client.session.put(key, rogue)
                client.session.put(key, b"\x00garbage")
            time.sleep(2.0)
            victim.check(t0)
            after = errors_by_kind(service)
            assert after.get("invalid_key", 0) - before.get("invalid_key", 0) >= 6
            assert service.metric("arcf_frames_dropped_total") - dropped_before < 5
            for kind in ("malformed_message", "stale_frame", "sequence_jump"):
                assert after.get(kind, 0) == before.get(kind, 0), kind
        finally:
            victim.close()


def test_a_rogue_frame_number_on_the_streams_own_key_cannot_lock_it_out(service, clip) -> None:
    with TrackingClient(connect=[service.endpoint]) as client:
        victim = Victim(client, clip, "victim-seq")
        try:
            dropped_before = service.metric("arcf_frames_dropped_total")
            t0 = time.monotonic()
            for seq in (10**12, 10**12 + 1):  # two in a row: still not enough to take over
                client.session.put(KEYS.frames("victim-seq"), encode(Frame(
                    stream_id="victim-seq", seq=seq, capture_ts_ns=1, encoding="jpeg",
                    payload=clip.frames[0])))
            time.sleep(2.0)
            victim.notices = [n for n in victim.notices if n.code.value != "sequence_jump"]
            window = victim.check(t0)
            assert window["dropped"] == 0
            assert service.metric("arcf_frames_dropped_total") - dropped_before < 5
            # a negative number is not a frame at all
            raw = msgpack.unpackb(encode(Frame(stream_id="victim-seq", seq=1, capture_ts_ns=1,
                                               encoding="jpeg", payload=b"x")), raw=False)
            raw["seq"] = -5
            client.session.put(KEYS.frames("victim-seq"), msgpack.packb(raw))
            time.sleep(1.0)
            assert [n.code.value for n in victim.notices] == ["invalid_request"]
            victim.notices.clear()
            victim.check(t0)
        finally:
            victim.close()


def test_a_flood_is_refused_at_intake_and_reported(service, clip) -> None:
    with TrackingClient(connect=[service.endpoint]) as client:
        victim = Victim(client, clip, "victim-flood")
        notices: list[ErrorMessage] = []
        sub = client.session.declare_subscriber(KEYS.errors("flooder"), lambda s: notices.append(
            decode(s.payload.to_bytes(), expected=ErrorMessage)))
        flooder = client.start("flooder", clip.box, preset="bacf", frame_seq=0)
        try:
            before = errors_by_kind(service)
            t0 = time.monotonic()
            for i in range(300):  # ~1000 frames/s for 0.3 s against a limit of 30/s
                client.publish_frame("flooder", data=clip.frames[i % len(clip)], seq=i)
                time.sleep(0.001)
            time.sleep(1.5)
            victim.check(t0)
            refused = errors_by_kind(service).get("rate_limited", 0) - before.get(
                "rate_limited", 0)
            assert refused >= 200  # the excess, counted one by one at intake
            assert "rate_limited" in [n.code.value for n in notices]
            assert any(f"{int(refused)} frame" in n.message or "frame(s) refused" in n.message
                       for n in notices)
        finally:
            client.stop(flooder.session_id)
            sub.undeclare()
            victim.close()


@pytest.mark.parametrize(("overrides", "words"), [
    ({"gamma": "x"}, "gamma must be a finite number"),
    ({"admm_iterations": 4000}, "admm_iterations must be an integer in [1, 20], got 4000"),
    ({"n_scales": 1000}, "n_scales must be an integer in [1, 15]"),
    ({"sampling": "fast"}, "sampling must be one of"),
])
def test_overrides_out_of_type_or_range_are_refused_before_any_worker(
        service, clip, overrides, words) -> None:
    with TrackingClient(connect=[service.endpoint]) as client:
        before = errors_by_kind(service).get("invalid_parameter", 0)
        with pytest.raises(ServiceError) as refused:
            client.start("overridden", clip.box, preset="arcf-hc", overrides=overrides)
        assert refused.value.code == "invalid_parameter"
        assert words in str(refused.value)
        assert errors_by_kind(service)["invalid_parameter"] == before + 1
        assert client.status().sessions == [] or all(
            s.stream_id != "overridden" for s in client.status().sessions)

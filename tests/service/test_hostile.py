"""A hostile (or merely broken) ground station against a real service on loopback.

One victim stream is tracked at 10 fps throughout; another station then does what a buggy or
malicious one can: puts frames and garbage on wildcard key expressions, numbers a frame 10^12,
floods its own stream, sends overrides of the wrong type or far outside their range. For each
attack: the victim's frames keep being processed (every frame sent gets a result or a counted
drop, in order, and its newest frame is answered: it is not locked out), the attacker gets a
documented error, and the service's counters say what happened. What an attack costs the
victim in latency is a figure of the machine: benchmarks/hostile.py measures it."""

from __future__ import annotations

import time
from typing import Any

import msgpack
import pytest

pytest.importorskip("zenoh")

from arcf.client import ServiceError, TrackingClient
from arcf.data import data_root
from arcf.loadtools.driver import Clip, Fleet, Pacing
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import wait_until
from arcf.registry import available_presets
from arcf.schemas import ErrorMessage, Frame, KeySpace, decode, encode
from arcf.service.scrape import by_label, fetch

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

KEYS = KeySpace()


@pytest.fixture(scope="module")
def service():
    svc = ServiceProcess("--max-stream-fps", "30")
    yield svc
    assert svc.stop() == 0


def errors_by_kind(svc: ServiceProcess) -> dict[str, float]:
    assert svc.metrics_url is not None
    return by_label(fetch(svc.metrics_url), "arcf_errors_total", "kind")


class Victim:
    """A well-behaved station: one stream at 10 fps, one session, its error notices."""

    def __init__(self, client: TrackingClient, clip: Clip, name: str) -> None:
        self.notices: list[ErrorMessage] = []
        self.sub = client.session.declare_subscriber(
            KEYS.errors(name), lambda s: self.notices.append(
                decode(s.payload.to_bytes(), expected=ErrorMessage)))
        self.fleet = Fleet(client, [clip], preset="bacf", pacing=Pacing.fixed_rate(10.0))
        (self.stream,) = self.fleet.add(names=[name])
        # running before the attack: its first result is in
        wait_until(lambda: bool(self.stream.record.received), timeout=30,
                   what=f"{name}'s first result")

    def caught_up(self, timeout: float = 30.0) -> int:
        """Wait until a frame the victim sent after this call, or a later one, has a result:
        every frame before it is then answered or counted in a ``dropped``, and anything put
        on the stream's key before the call has been through the service. Returns that
        frame's number."""
        rec, called = self.stream.record, time.monotonic()
        wait_until(lambda: bool(rec.sent) and rec.sent[-1][1] >= called, timeout=timeout,
                   what=f"a frame of {rec.name} sent")
        last = rec.sent[-1][0]
        wait_until(lambda: bool(rec.received) and rec.received[-1].frame_seq >= last,
                   timeout=timeout, what=f"a result for frame {last} of {rec.name} or later")
        return last

    def check(self, t0: float) -> dict[str, Any]:
        """Since ``t0``: the victim's newest frame is answered (it was served throughout, not
        locked out), every frame it sent is answered or reported dropped, in order, nothing
        it never sent is counted as dropped, and it got no error notice."""
        self.caught_up()
        rec = self.stream.record
        window = self.fleet.window(t0, time.monotonic())
        counts = rec.accounting()
        assert window["results"] > 0 and window["errors"] == 0, window
        assert window["dropped"] <= len(rec.sent), window  # frames it sent, not phantoms
        assert counts["unaccounted"] == 0 and counts["out_of_order"] == 0, counts
        assert self.notices == [], [n.code for n in self.notices]
        return window

    def noticed(self, code: str, t0: float) -> None:
        """An attack on the victim's own key earns it one notice: wait for it, let the
        victim's frames sent after it through (nothing else came of the attack), assert it is
        exactly one ``code`` notice, and :meth:`check` the window since ``t0`` as usual."""
        wait_until(lambda: bool(self.notices), timeout=30, what="a notice to the victim")
        self.caught_up()
        assert [n.code.value for n in self.notices] == [code]
        self.notices.clear()
        self.check(t0)

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
            wait_until(lambda: errors_by_kind(service).get("invalid_key", 0)
                       - before.get("invalid_key", 0) >= 6, timeout=30,
                       what="the six puts refused as invalid_key")
            victim.check(t0)
            after = errors_by_kind(service)
            # what was dropped meanwhile is the victim's own frames (a slow machine's queue),
            # never the 10^12 frames a rogue number would count as lost
            assert service.metric("arcf_frames_dropped_total") - dropped_before <= \
                victim.stream.sent
            for kind in ("malformed_message", "stale_frame", "sequence_jump"):
                assert after.get(kind, 0) == before.get(kind, 0), kind
        finally:
            victim.close()


def test_a_rogue_frame_number_on_the_streams_own_key_cannot_lock_it_out(service, clip) -> None:
    with TrackingClient(connect=[service.endpoint]) as client:
        victim = Victim(client, clip, "victim-seq")
        try:
            dropped_before = service.metric("arcf_frames_dropped_total")
            jumps_before = errors_by_kind(service).get("sequence_jump", 0)
            t0 = time.monotonic()
            for seq in (10**12, 10**12 + 1):  # two in a row: still not enough to take over
                client.session.put(KEYS.frames("victim-seq"), encode(Frame(
                    stream_id="victim-seq", seq=seq, capture_ts_ns=1, encoding="jpeg",
                    payload=clip.frames[0])))
            wait_until(lambda: errors_by_kind(service).get("sequence_jump", 0) > jumps_before,
                       timeout=30, what="the rogue frames refused as sequence_jump")
            victim.caught_up()  # its frames after the rogue ones are through as well
            victim.notices = [n for n in victim.notices if n.code.value != "sequence_jump"]
            window = victim.check(t0)
            # the victim's numbering held: no gap of 10^12 frames counted as lost, only (on a
            # slow machine) some of the frames it did send
            assert window["dropped"] <= victim.stream.sent
            assert service.metric("arcf_frames_dropped_total") - dropped_before <= \
                victim.stream.sent
            # a negative number is not a frame at all
            raw = msgpack.unpackb(encode(Frame(stream_id="victim-seq", seq=1, capture_ts_ns=1,
                                               encoding="jpeg", payload=b"x")), raw=False)
            raw["seq"] = -5
            client.session.put(KEYS.frames("victim-seq"), msgpack.packb(raw))
            victim.noticed("invalid_request", t0)
        finally:
            victim.close()


def test_a_flood_is_refused_at_intake_and_reported(service, clip) -> None:
    with TrackingClient(connect=[service.endpoint]) as client:
        victim = Victim(client, clip, "victim-flood")
        notices: list[ErrorMessage] = []
        sub = client.session.declare_subscriber(KEYS.errors("flooder"), lambda s: notices.append(
            decode(s.payload.to_bytes(), expected=ErrorMessage)))
        answers: list[Any] = []
        results = client.results("flooder", callback=answers.append)
        flooder = client.start("flooder", clip.box, preset="bacf", frame_seq=0)
        try:
            before = errors_by_kind(service)

            def refused() -> float:
                return errors_by_kind(service).get("rate_limited", 0) - before.get(
                    "rate_limited", 0)

            t0 = time.monotonic()
            for i in range(300):  # the stimulus: up to ~1000 frames/s against a limit of 30/s
                client.publish_frame("flooder", data=clip.frames[i % len(clip)], seq=i)
                time.sleep(0.001)
            # then a 5 fps camera on the same key until one of its frames is answered: frames
            # of one key pass the intake in order, so the whole flood has been through it
            seq, deadline = 300, time.monotonic() + 60
            while not any(r.frame_seq >= 300 and r.status.value not in ("stopped", "stale")
                          for r in list(answers)):
                assert time.monotonic() < deadline, "no frame after the flood answered in 60 s"
                client.publish_frame("flooder", data=clip.frames[seq % len(clip)], seq=seq)
                seq += 1
                time.sleep(0.2)  # the stimulus: 5 fps, within the limit
            t1 = time.monotonic()
            victim.check(t0)
            # the bucket lets through one second's worth plus 30/s while the flood arrived
            # (between t0 and t1 at most, however slowly this machine sent or received it);
            # everything beyond is refused, counted one by one at intake (of the refusals,
            # seq - 300 at most can be frames of the 5 fps camera)
            allowed = 30 * (1 + (t1 - t0))
            assert refused() - (seq - 300) >= 300 - allowed, (refused(), seq, t1 - t0)
            wait_until(lambda: "rate_limited" in [n.code.value for n in notices], timeout=10,
                       what="the flooder's rate_limited notice")
            assert any(f"{int(refused())} frame" in n.message or "frame(s) refused" in n.message
                       for n in notices)
        finally:
            client.stop(flooder.session_id)
            results.close()
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


# ---------------------------------------------------------------------------- session lifetime
@pytest.fixture(scope="module")
def strict():
    """A service with short lifetimes, to see sessions end within a test's time."""
    svc = ServiceProcess("--session-idle-s", "2", "--client-grace-s", "1",
                         "--max-sessions", "4")
    yield svc
    assert svc.stop() == 0


class Watcher:
    """Results of a stream, watched by a client of its own (one that outlives the station)."""

    def __init__(self, client: TrackingClient, stream: str) -> None:
        self.results: list[Any] = []
        self.sub = client.results(stream, callback=self.results.append)

    def wait_for(self, status: str, timeout: float) -> Any:
        def hits() -> list[Any]:
            return [r for r in self.results if r.status.value == status]

        wait_until(lambda: bool(hits()), timeout=timeout, what=f"a {status} result (so far: "
                   f"{[(r.frame_seq, r.status.value) for r in self.results]})")
        return hits()[0]


class Frames:
    """Frames of one stream, published at 10 fps by a client that is not the station: the
    stream stays busy (no session idles out) whatever happens to the station."""

    def __init__(self, client: TrackingClient, clip: Clip, stream: str) -> None:
        self.client, self.clip, self.stream, self.seq = client, clip, stream, 0

    def run(self, seconds: float, until: Any = None) -> None:
        """Publish for ``seconds`` (the stimulus: a stream that stays busy), or until
        ``until()`` holds (then ``seconds`` is a generous deadline, not a figure)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not (until and until()):
            self.client.publish_frame(self.stream, seq=self.seq,
                                      data=self.clip.frames[self.seq % len(self.clip)])
            self.seq += 1
            time.sleep(0.1)  # the stimulus: a 10 fps camera


def test_a_quiet_stream_ends_its_sessions_saying_why(strict, clip) -> None:
    with TrackingClient(connect=[strict.endpoint]) as client:
        watch = Watcher(client, "quiet")
        ack = client.start("quiet", clip.box, preset="bacf", frame_seq=0)
        for i in range(3):
            client.publish_frame("quiet", data=clip.frames[i], seq=i)
            time.sleep(0.1)  # the stimulus: three frames of a 10 fps camera, then quiet
        t_quiet = time.monotonic()  # after the last frame was published
        status = client.status(stream_id="quiet")
        (info,) = status.sessions
        assert info.session_id == ack.session_id and info.client_id == client.client_id
        stopped = watch.wait_for("stopped", timeout=30)
        # not before its idle limit (2 s) from its last frame; how much later is the machine's
        assert time.monotonic() - t_quiet >= 2.0
        assert stopped.code.value == "session_expired" and "no frame" in stopped.message
        # the worker tells its control plane after its last result: the status follows
        wait_until(lambda: client.status(stream_id="quiet").sessions == [], timeout=30,
                   what="the expired session gone from the status")
        assert errors_by_kind(strict)["session_expired"] >= 1


def test_sessions_of_a_vanished_station_end_and_free_their_places(strict, clip) -> None:
    # a station starts as many sessions as the instance allows, then is SIGKILLed
    script = (
        "import sys, time\n"
        "from arcf.client import TrackingClient\n"
        f"c = TrackingClient(connect=[{strict.endpoint!r}])\n"
        "for k in range(4):\n"
        f"    c.start(f'flood-{{k}}', {list(clip.box)!r}, preset='bacf')\n"
        "print('started', flush=True)\n"
        "time.sleep(60)\n")
    import subprocess
    import sys

    station = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                               text=True)
    try:
        assert station.stdout is not None and station.stdout.readline().strip() == "started"
        with TrackingClient(connect=[strict.endpoint]) as client:
            with pytest.raises(ServiceError) as full:
                client.start("legit", clip.box, preset="bacf")
            assert full.value.code == "limit_exceeded"
            watch, frames = Watcher(client, "flood-0"), Frames(client, clip, "flood-0")
            station.kill()
            station.wait(timeout=10)
            # frames keep flowing, so that the station's absence ends the session, not idling
            frames.run(60, until=lambda: any(r.status.value == "stopped"
                                             for r in watch.results))  # lease + grace
            stopped = watch.wait_for("stopped", timeout=1)
            assert stopped.code.value == "session_expired" and "station" in stopped.message
            wait_until(lambda: [s for s in client.status().sessions
                                if s.stream_id.startswith("flood")] == [], timeout=30,
                       what="the vanished station's four sessions ended")
            ack = client.start("legit", clip.box, preset="bacf")
            client.stop(ack.session_id)
    finally:
        station.kill()
        station.wait(timeout=10)


def test_a_station_that_reconnects_within_the_grace_keeps_its_sessions(strict, clip) -> None:
    with TrackingClient(connect=[strict.endpoint]) as observer:
        frames = Frames(observer, clip, "keep")  # busy: the idle limit (2 s) stays out of it
        first = TrackingClient(connect=[strict.endpoint], client_id="station-7")
        ack = first.start("keep", clip.box, preset="bacf", frame_seq=0)
        first.close()  # token gone...
        again = TrackingClient(connect=[strict.endpoint], client_id="station-7")  # ...and back
        try:
            frames.run(2.5)  # the stimulus: past the grace (1 s), checked once a second
            assert [s.session_id for s in observer.status(stream_id="keep").sessions] == [
                ack.session_id]
        finally:
            # the station's own session: it kept the control token over its restart
            again.stop(ack.session_id, control_token=ack.control_token)
            again.close()


def test_a_restarted_station_adopts_the_sessions_it_left_behind(strict, clip) -> None:
    with TrackingClient(connect=[strict.endpoint]) as observer:
        watch, frames = Watcher(observer, "adopted"), Frames(observer, clip, "adopted")
        first = TrackingClient(connect=[strict.endpoint])  # a random client_id per run
        ack = first.start("adopted", clip.box, preset="bacf", frame_seq=0)
        frames.run(0.5)
        first.close()  # the station restarts, under a new id
        second = TrackingClient(connect=[strict.endpoint])
        try:
            (info,) = second.status(stream_id="adopted").sessions
            assert (info.session_id, info.client_id) == (ack.session_id, first.client_id)
            # without the control token its first run kept, the session is not its to adopt
            with pytest.raises(ServiceError) as refused:
                second.reinit(ack.session_id, clip.box, adopt=True)
            assert refused.value.code == "forbidden"
            assert ack.control_token is not None
            second.reinit(ack.session_id, clip.box, adopt=True, control_token=ack.control_token)
            assert second.status(stream_id="adopted").sessions[0].client_id == second.client_id
            frames.run(2.5)  # past the first station's grace (1 s), checked once a second
            assert [r for r in watch.results if r.status.value == "stopped"] == []
        finally:
            second.close()
        # the adopting station is gone in turn: the session follows its token now
        frames.run(60, until=lambda: any(r.status.value == "stopped" for r in watch.results))
        stopped = watch.wait_for("stopped", timeout=1)
        assert stopped.code.value == "session_expired" and second.client_id in stopped.message
        with pytest.raises(ValueError, match="tie_sessions"):
            TrackingClient(connect=[strict.endpoint], tie_sessions=False).reinit(
                ack.session_id, clip.box, adopt=True)


def test_a_station_token_never_seen_has_the_grace_to_appear(strict, clip) -> None:
    from arcf.schemas import Ack, StartRequest

    with TrackingClient(connect=[strict.endpoint]) as client:
        watch, frames = Watcher(client, "ghost"), Frames(client, clip, "ghost")
        start = StartRequest(request_id="ghost-1", stream_id="ghost", box=list(clip.box),
                             preset="bacf", frame_seq=0, client_id="no-such-station")
        (reply,) = list(client.session.get(KEYS.control(), payload=encode(start), timeout=5))
        decode(reply.ok.payload.to_bytes(), expected=Ack)
        frames.run(60, until=lambda: any(r.status.value == "stopped" for r in watch.results))
        stopped = watch.wait_for("stopped", timeout=1)
        # the token's grace ended it (the message names the station), not the idle rule
        assert stopped.code.value == "session_expired" and "no-such-station" in stopped.message
        assert frames.seq > 5  # the frames kept flowing meanwhile: not an idle end


def test_a_box_outside_its_frame_ends_the_session_visibly(strict, clip) -> None:
    with TrackingClient(connect=[strict.endpoint]) as client:
        watch = Watcher(client, "outside")
        client.start("outside", (5000.0, 5000.0, 20.0, 20.0), preset="bacf", frame_seq=0)
        client.publish_frame("outside", data=clip.frames[0], seq=0)
        stopped = watch.wait_for("stopped", timeout=30)
        (error,) = [r for r in watch.results if r.status.value == "error"]
        assert error.code.value == "invalid_box" and error.frame_seq == 0
        assert stopped.code.value == "invalid_box" and "does not fit frame 0" in stopped.message
        # the worker ends the session and tells the control plane, which the status reads:
        # the two travel apart, so the status is waited for (a deadline, not a delay)
        wait_until(lambda: client.status(stream_id="outside").sessions == [], timeout=30,
                   what="the ended session gone from the status")


def test_frame_seq_in_the_past_present_and_future(service, clip) -> None:
    # (the module's lenient service: its sessions do not idle out while the test waits)
    with TrackingClient(connect=[service.endpoint]) as client:
        watch = Watcher(client, "seqs")
        first = client.start("seqs", clip.box, preset="bacf", frame_seq=0)

        def answered(session_id: str, seq: int) -> bool:
            return any(r.session_id == session_id and r.frame_seq >= seq
                       and r.status.value not in ("stopped", "stale") for r in watch.results)

        for i in range(5):
            client.publish_frame("seqs", data=clip.frames[i], seq=i)
            time.sleep(0.05)  # the stimulus: a 20 fps camera
        wait_until(lambda: answered(first.session_id, 4), timeout=30, what="frame 4 tracked")
        with pytest.raises(ServiceError) as far:  # beyond max_seq_gap: it may never come
            client.start("seqs", clip.box, preset="bacf", frame_seq=10**6)
        assert far.value.code == "invalid_request" and "frame_seq" in str(far.value)
        later = client.start("seqs", clip.box, preset="bacf", frame_seq=8)  # waits for 8
        past = client.start("seqs", clip.box, preset="bacf", frame_seq=2)  # drawn on frame 2

        def states() -> dict[str, Any]:
            return {s.session_id: s for s in client.status(stream_id="seqs").sessions}

        # the workers report once a second: until the first session's five frames are in it
        wait_until(lambda: states()[first.session_id].frames == 5, timeout=30,
                   what="the workers' report of the first session's frames")
        now = states()
        assert now[later.session_id].state == "waiting"
        assert now[first.session_id].state == "tracking"
        assert now[first.session_id].frames == 5 and now[first.session_id].last_seq == 4
        for i in range(5, 10):
            client.publish_frame("seqs", data=clip.frames[i], seq=i)
            time.sleep(0.05)  # the stimulus: a 20 fps camera
        wait_until(lambda: answered(first.session_id, 9) and answered(later.session_id, 9)
                   and answered(past.session_id, 9), timeout=30, what="frame 9 tracked")
        # (their stream was quiet over a second meanwhile: stale notices, not about frames)
        mine = {sid: [r for r in watch.results if r.session_id == sid
                      and r.status.value != "stale"]
                for sid in (later.session_id, past.session_id)}
        assert mine[later.session_id][0].frame_seq == 8
        assert mine[later.session_id][0].status.value == "initialized"
        assert mine[past.session_id][0].frame_seq == 5
        assert "box of frame 2 applied to frame 5" in (mine[past.session_id][0].message or "")
        for sid in (first.session_id, later.session_id, past.session_id):
            client.stop(sid)
        # a station's stop ends the session's results with a last `stopped`, without a code
        wait_until(lambda: len([r for r in watch.results if r.status.value == "stopped"]) >= 3,
                   timeout=30, what="each stopped session's last result")
        ends = [r for r in watch.results if r.status.value == "stopped"]
        assert {r.session_id for r in ends} == {first.session_id, later.session_id,
                                                past.session_id}
        assert all(r.code is None and "stop request" in r.message for r in ends)
        assert next(r for r in ends if r.session_id == first.session_id).frame_seq == 9


def test_a_session_over_its_budget_ends_and_says_so(clip) -> None:
    svc = ServiceProcess("--session-budget-ms", "0.5")  # every real frame is over this
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            watch = Watcher(client, "heavy")
            client.start("heavy", clip.box, preset="arcf-hc", frame_seq=0)
            for i in range(10):
                client.publish_frame("heavy", data=clip.frames[i], seq=i)
                time.sleep(0.1)  # the stimulus: a 10 fps camera
            stopped = watch.wait_for("stopped", timeout=30)
            assert stopped.code.value == "limit_exceeded" and "budget" in stopped.message
            # a frame over 4x the budget ends it at once; a mean over it after 5 frames
            assert 1 <= len([r for r in watch.results
                             if r.status.value not in ("stopped", "stale")]) <= 6
            # the worker tells its control plane after its last result: the status follows
            wait_until(lambda: client.status().sessions == [], timeout=30,
                       what="the ended session gone from the status")
    finally:
        assert svc.stop() == 0


def test_oversized_frames_are_refused_where_they_can_be_seen(service, clip) -> None:
    """Up to the transport's limit (4 x max_payload) an oversized frame reaches the service and
    is refused and reported; the SDK refuses it before sending; beyond the limit the service's
    transport discards it without holding it, and nothing else is disturbed."""
    import os

    import zenoh

    with TrackingClient(connect=[service.endpoint]) as client:
        victim = Victim(client, clip, "victim-big")
        try:
            with pytest.raises(ValueError, match="max_payload"):
                client.publish_frame("victim-big", data=b"x" * (9 << 20), seq=10**6)
            before = errors_by_kind(service).get("oversized_payload", 0)
            t0 = time.monotonic()
            for mib, seq in ((12, 10**6), (200, 10**6 + 1)):
                client.session.put(KEYS.frames("victim-big"), encode(Frame(
                    stream_id="victim-big", seq=seq, capture_ts_ns=1, encoding="jpeg",
                    payload=os.urandom(mib << 20))),
                    congestion_control=zenoh.CongestionControl.BLOCK)
            victim.noticed("oversized_payload", t0)  # once both are through
            assert errors_by_kind(service)["oversized_payload"] == before + 1
        finally:
            victim.close()


def test_the_service_says_what_each_override_accepts(service, clip) -> None:
    """The presets reply lists every wire override with its range; each preset's values are
    inside; a value just outside a bound is refused, one just inside accepted."""
    with TrackingClient(connect=[service.endpoint]) as client:
        answer = client.presets()
        params = {p.name: p for p in answer.parameters}
        assert {"admm_iterations", "gamma", "sampling", "n_scales", "scale_filter.n_scales",
                "state.reacquire", "state.update_policy"} <= set(params)
        assert params["state.reacquire"].kind == "bool"
        assert params["admm_iterations"].kind == "int" and params["admm_iterations"].maximum == 20
        assert params["sampling"].choices == ["release", "pyramid"]
        # ARCF's three, and the Siamese ones and the hybrid where their network files are
        runnable = sorted(name for name, why in available_presets().items() if not why)
        assert sorted(p.name for p in answer.presets) == runnable
        assert {"arcf-h", "arcf-hc", "bacf"} <= set(runnable)
        for preset in answer.presets:
            for name, value in preset.values.items():
                p = params[name]
                assert p.minimum is None or value >= p.minimum
                assert p.maximum is None or value <= p.maximum
                assert p.choices is None or value in p.choices
        limit = int(params["admm_iterations"].maximum)
        with pytest.raises(ServiceError, match="admm_iterations"):
            client.start("ranges", clip.box, preset="bacf",
                         overrides={"admm_iterations": limit + 1})
        ack = client.start("ranges", clip.box, preset="bacf",
                           overrides={"admm_iterations": limit})
        client.stop(ack.session_id)

"""The control plane against fake workers (in-process queues, no Zenoh): it stays responsive
whatever the workers report, and stations that vanish cost neither threads nor memory."""

from __future__ import annotations

import queue
import threading
import time
from typing import Any

from arcf.loadtools.waiting import wait_until
from arcf.schemas import StartRequest, decode, encode
from arcf.service.commands import Confirmation, SessionsEnded, SessionStats, StartSession
from arcf.service.control import ControlPlane
from arcf.service.settings import ServiceSettings


class FakeWorker:
    """Confirms every command; before confirming the ``end_first``-th start, reports a session
    it ended by itself (as a worker does when a box does not fit its frame)."""

    def __init__(self, commands: queue.Queue, responses: queue.Queue, end_first: int) -> None:
        self.commands, self.responses, self.end_first = commands, responses, end_first
        self.starts = 0
        threading.Thread(target=self.run, daemon=True).start()

    def run(self) -> None:
        while True:
            cmd = self.commands.get()
            if isinstance(cmd, StartSession):
                self.starts += 1
                if self.starts == self.end_first:
                    self.responses.put(SessionsEnded(0, ("ended-by-worker",), "box"))
            self.responses.put(Confirmation(cmd.reply_id or "", True))


def _plane(**settings: Any) -> tuple[ControlPlane, FakeWorker]:
    commands: queue.Queue = queue.Queue()
    responses: queue.Queue = queue.Queue()
    # a worker that never confirms fails a request after ``timeout``: generous, so that only
    # a stalled pump (never a slow machine) gets there
    plane = ControlPlane(ServiceSettings(workers=1, **settings), [commands], "test",
                         responses=responses, timeout=30.0)
    return plane, FakeWorker(commands, responses, end_first=2)


def _start(plane: ControlPlane, stream: str, **fields: Any) -> Any:
    reply = plane.handle(encode(StartRequest(request_id=f"r-{stream}", stream_id=stream,
                                             box=[1, 1, 5, 5], preset="bacf", **fields)))
    assert reply is not None
    return decode(reply)


def test_a_session_ended_by_a_worker_does_not_stall_requests() -> None:
    plane, _ = _plane()
    _start(plane, "a")
    with plane.op_lock:  # a request in progress holds this while the pump delivers
        reply = _start(plane, "b")  # its worker reports an ended session first
    # confirmed while the lock was held: a pump stalled on the ended session would have left
    # the request unconfirmed, an error after the plane's timeout
    assert reply.type == "ack", reply


def test_vanished_stations_cost_no_thread_and_no_memory() -> None:
    plane, _ = _plane(client_grace_s=0.2)
    threads = threading.active_count()
    for k in range(500):  # token churn of stations that hold no session here
        plane.client_token(f"st-{k}", True)
        plane.client_token(f"st-{k}", False)
    assert threading.active_count() <= threads + 1
    assert plane.live_clients == set() and plane.client_deadlines == {}
    ack = _start(plane, "kept", client_id="owner")
    plane.client_token("owner", True)
    plane.client_token("owner", False)
    plane.client_token("owner", True)  # back within the grace: nothing ends
    assert plane.client_deadlines == {}
    plane.client_token("owner", False)
    time.sleep(0.3)  # the stimulus: the station stays away past its grace (0.2 s)
    plane.responses.put(SessionStats(0, {}))  # the once-a-second reports check deadlines
    wait_until(lambda: ack.session_id not in plane.sessions, timeout=30,
               what="the session of the vanished station ended")


def test_a_presets_request_checks_a_start_as_a_start_is_checked() -> None:
    """One validator: a ``presets_request`` naming a preset answers what a ``start`` with it
    would get, from the same check, and starts nothing."""
    from arcf.schemas import ErrorCode, PresetsRequest

    plane, worker = _plane()

    def check(preset: str, **overrides: Any) -> tuple[Any, Any]:
        reply = decode(plane.handle(encode(PresetsRequest(
            request_id="p", preset=preset, overrides=overrides))) or b"")
        return reply.refused, reply.refusal

    assert check("ARCF_HC", **{"state.reacquire": True}) == (None, None)
    for preset, overrides, code, fragment in (
            ("arcf-x", {}, ErrorCode.UNKNOWN_PRESET, "unknown preset 'arcf-x'"),
            ("bacf", {"gamma": 1e9}, ErrorCode.INVALID_PARAMETER, "gamma must be"),
            ("bacf", {"no_such": 1}, ErrorCode.INVALID_PARAMETER, "unknown parameter"),
            ("bacf", {"fhog_sse_table": "/etc/passwd"}, ErrorCode.INVALID_PARAMETER,
             "names a file on the service's host")):
        refused, refusal = check(preset, **overrides)
        start = _start(plane, "s", overrides=overrides) if preset == "bacf" else None
        assert refused is code and fragment in refusal, (preset, overrides)
        if start is not None:  # the start itself gets the same answer
            assert start.type == "error" and start.code is code and start.message == refusal
    assert worker.starts == 0 and plane.sessions == {}


def test_a_readiness_check_is_answered_by_the_instance_it_checks_only() -> None:
    """Instances starting side by side can each see a different live set: a readiness check
    answered by whichever instance thinks it owns the stream would leave a session there that
    nothing ends (it is in no registry)."""
    from arcf.schemas import KeySpace
    from arcf.service.cluster import Cluster, owner
    from arcf.service.control import readiness_instance, readiness_stream

    # one id the prefix of another, and one's check owned by the other by hash
    ids = next(ids for ids in ([f"inst-{k}", f"inst-{k}-2"] for k in range(1000))
               if any(owner(readiness_stream(i), ids) != i for i in ids))
    checked = next(i for i in ids if owner(readiness_stream(i), ids) != i)
    other = next(i for i in ids if i != checked)
    planes = {}
    for i in ids:
        cluster = Cluster(session=None, keys=KeySpace(), instance_id=i)
        cluster.members = set(ids)
        planes[i], _ = _plane(instance_id=i)
        planes[i].cluster = cluster
    assert readiness_instance(readiness_stream(checked)) == checked
    request = encode(StartRequest(request_id="r", stream_id=readiness_stream(checked),
                                  box=[1, 1, 5, 5], preset="bacf"))
    assert planes[other].handle(request) is None  # the stream's owner by hash stays silent
    reply = planes[checked].handle(request)
    assert reply is not None and decode(reply).type == "ack"
    assert planes[checked].end_readiness_checks() == 1

"""Who may stop or re-draw a session over the Zenoh control key (docs/service-design.md, "Who
may do what"): a real ``arcf-service`` on loopback without an ACL, stations as separate
clients. By default (``session_control = "owner"``) only the holder of a session's control
token, which the start's ack carries to the starter alone, may stop or re-draw it; every
refusal is ``forbidden``, visible to the requester and counted. With ``"open"`` any station
may. (tests/service/test_access_control.py checks the same rule behind the deployment's ACL;
tests/adapters/test_liveview_control.py, test_ros2.py and test_mavlink_hardening.py the
adapters' side.)"""

from __future__ import annotations

import uuid

import pytest

pytest.importorskip("zenoh")

from arcf.client import ServiceError, TrackingClient
from arcf.loadtools.procs import ServiceProcess
from arcf.schemas import Ack, ErrorMessage, KeySpace, ReinitRequest, StopRequest, decode, encode
from arcf.service.scrape import by_label, fetch

pytestmark = pytest.mark.integration
BOX = (10.0, 10.0, 40.0, 40.0)


def _raw(client: TrackingClient, request: StopRequest | ReinitRequest) -> Ack | ErrorMessage:
    """A request as a client written from the wire contract sends it: msgpack on the
    control key, the reply decoded by hand."""
    (reply,) = list(client.session.get(KeySpace().control(), payload=encode(request),
                                       timeout=10))
    assert reply.ok is not None
    return decode(reply.ok.payload.to_bytes(), expected=(Ack, ErrorMessage))


def test_only_the_holder_of_a_sessions_token_may_stop_or_redraw_it() -> None:
    with ServiceProcess(workers=1) as svc, \
            TrackingClient(connect=[svc.endpoint]) as owner, \
            TrackingClient(connect=[svc.endpoint]) as stranger:
        ack = owner.start("cam-a", BOX, preset="bacf")
        token = ack.control_token
        assert token is not None and len(token) >= 16
        assert owner.control_tokens == {ack.session_id: token}
        # another station sees the session but may not touch it
        assert [s.session_id for s in stranger.status("cam-a").sessions] == [ack.session_id]
        refusals = 0
        for act in (lambda: stranger.stop(ack.session_id),
                    lambda: stranger.reinit(ack.session_id, BOX),
                    lambda: stranger.stop(ack.session_id, control_token="x" * 32)):
            with pytest.raises(ServiceError) as refused:
                act()
            refusals += 1
            assert refused.value.code == "forbidden"
            assert refused.value.error.session_id == ack.session_id
        # the same over the raw wire: without the token refused, with it carried out
        reply = _raw(stranger, ReinitRequest(request_id=uuid.uuid4().hex,
                                             session_id=ack.session_id, box=list(BOX)))
        refusals += 1
        assert isinstance(reply, ErrorMessage) and reply.code == "forbidden"
        reply = _raw(stranger, ReinitRequest(request_id=uuid.uuid4().hex,
                                             session_id=ack.session_id, box=list(BOX),
                                             control_token=token))
        assert isinstance(reply, Ack) and reply.control_token is None  # starts only
        assert [s.session_id for s in owner.status("cam-a").sessions] == [ack.session_id]
        # the token handed over is a handover of control: the stranger stops it
        stranger.stop(ack.session_id, control_token=token)
        assert owner.status("cam-a").sessions == []
        # each session has its own token
        a, b = owner.start("cam-b", BOX, preset="bacf"), owner.start("cam-c", BOX, preset="bacf")
        assert a.control_token != b.control_token
        with pytest.raises(ServiceError) as refused:
            stranger.stop(b.session_id, control_token=a.control_token)
        refusals += 1
        assert refused.value.code == "forbidden"
        owner.stop(a.session_id)
        owner.stop(b.session_id)
        assert owner.status().sessions == []
        assert svc.metrics_url is not None
        text = fetch(svc.metrics_url)
        assert by_label(text, "arcf_errors_total", "kind").get("forbidden") == refusals
        outcomes = {(labels["type"], labels["outcome"]): v for labels, v in _series(
            text, "arcf_control_requests_total")}
        assert outcomes[("stop", "forbidden")] == 3 and outcomes[("reinit", "forbidden")] == 2


def test_an_open_service_lets_any_station_stop_or_redraw() -> None:
    with ServiceProcess("--session-control", "open", workers=1) as svc, \
            TrackingClient(connect=[svc.endpoint]) as owner, \
            TrackingClient(connect=[svc.endpoint]) as other:
        ack = owner.start("cam-o", BOX, preset="bacf")
        other.reinit(ack.session_id, BOX)
        other.stop(ack.session_id)
        assert owner.status().sessions == []


def _series(text: str, name: str) -> list[tuple[dict[str, str], float]]:
    from arcf.service.scrape import series

    return series(text).get(name, [])

"""Ready means ready: the service's ready line and health check come only after it served a
start of its own through its control key, so a station that starts a session the moment it
sees either is answered within its default wait (5 s), by a real service."""

from __future__ import annotations

import pytest

pytest.importorskip("zenoh")

from arcf.client import TrackingClient
from arcf.loadtools.procs import ServiceProcess
from arcf.service.health import check

pytestmark = pytest.mark.integration


@pytest.mark.parametrize("workers", [1, 2])
def test_a_start_right_after_ready_is_served(workers: int) -> None:
    svc = ServiceProcess(workers=workers)  # returns at the ready line
    try:
        assert "a start served in" in svc.ready_line
        assert svc.metrics_url is not None
        assert check(svc.metrics_url) == (True, f"ok: {workers} workers")
        with TrackingClient(connect=[svc.endpoint]) as client:
            acks = [client.start(f"cam{k}", [10, 10, 40, 40], preset="bacf")
                    for k in range(workers)]  # the client's default wait: 5 s
            # the start-up's own session is gone: only the station's are there
            assert sorted(s.session_id for s in client.status().sessions) == sorted(
                a.session_id for a in acks)
    finally:
        assert svc.stop() == 0

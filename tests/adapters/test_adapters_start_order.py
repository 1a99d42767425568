"""The adapters start in any order: each command waits for the service with a line saying
what it waits for (bounded by ``--wait-s``), goes on once the service answers, and gives up
with a reason and exit status 2, never a traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("zenoh")

from arcf.loadtools.procs import free_port
from arcf.loadtools.waiting import wait_until

COMMANDS = {
    "mavlink": ["arcf.adapters.mavlink", "--camera", "cam", "--mavlink",
                "udpout:127.0.0.1:9"],
    "ros2": ["arcf.adapters.ros2", "--image", "/camera/image=cam"],
    "view": ["arcf.adapters.liveview", "--port", "0"],
    "record": ["arcf.adapters.record", "cam", "--out", "{tmp}"],
    "ingest": ["arcf.adapters.ingest", "rtp://127.0.0.1:9", "--stream", "cam"],
}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_without_a_service_each_adapter_gives_up_with_a_reason(name: str, tmp_path) -> None:
    args = [a.replace("{tmp}", str(tmp_path)) for a in COMMANDS[name]]
    out = subprocess.run([sys.executable, "-m", *args, "-e", f"tcp/127.0.0.1:{free_port()}",
                          "--wait-s", "1"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "Traceback" not in out.stderr
    assert "waiting for the tracking service: no Zenoh router at" in out.stderr
    assert "did not answer" in out.stderr and "giving up" in out.stderr


def test_an_adapter_started_first_goes_on_when_the_service_comes(
        tmp_path, started_before_the_service) -> None:
    """``arcf-record`` before the service: it waits, then records once the service is up
    (and, terminated after it, exits cleanly)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with started_before_the_service(
            [sys.executable, "-m", "arcf.adapters.record", "cam", "--out", str(tmp_path),
             "-e", endpoint, "--wait-s", "120"], endpoint) as early:
        wait_until(lambda: any("the tracking service answers" in x for x in early.lines),
                   timeout=120, what="the service found")
        assert early.proc.poll() is None  # recording, not exited
    assert early.code == 0 and "Traceback" not in "".join(early.lines)

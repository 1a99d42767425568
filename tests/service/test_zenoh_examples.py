"""zenoh-python's own example programs, unmodified, against a real service: ``z_get`` asks the
control queryable in JSON and prints the service's JSON replies, ``z_sub`` prints a session's
results from their JSON mirror key. Clients nobody here wrote, as docs/wire-contract.md shows
them. The examples come from zenoh-python's source package (``python
tools/zenoh_examples.py``, which ``.ci/run`` runs)."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("zenoh")

from arcf.client import TrackingClient
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
from zenoh_examples import examples_dir

EXAMPLES = examples_dir()
pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(not (EXAMPLES / "z_sub.py").is_file(),
                       reason=f"zenoh-python's examples are not in {EXAMPLES}: "
                              "python tools/zenoh_examples.py fetches them"),
    pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                       reason="needs ../shared/data"),
]

#: how the examples print what they receive: ``('<key>': '<payload as text>')``
RECEIVED = re.compile(r">> (?:\[Subscriber\] )?Received.*?\('([^']*)': '(.*)'\)$")


def _example(name: str, *args: str, endpoint: str) -> list[str]:
    """The example as its README runs it, a client of the service's router."""
    return [sys.executable, str(EXAMPLES / name), "-m", "client", "-e", endpoint,
            "--no-multicast-scouting", *args]


def z_get(endpoint: str, payload: str) -> list[tuple[str, Any]]:
    """``z_get`` on the control key with ``payload``: each reply's key and parsed JSON."""
    out = subprocess.run(_example("z_get.py", "-s", "arcf/v1/control", "-t", "ALL",
                                  "-p", payload, endpoint=endpoint),
                         capture_output=True, text=True, timeout=120, check=True).stdout
    return [(m[1], json.loads(m[2])) for line in out.splitlines()
            if (m := RECEIVED.match(line))]


@pytest.fixture
def service() -> Iterator[str]:
    with ServiceProcess(workers=1) as svc:
        yield svc.endpoint


def test_z_get_asks_the_service_in_json(service: str) -> None:
    (reply,) = z_get(service, '{"v": 1, "type": "status_request", "request_id": "z-get-1"}')
    key, status = reply
    assert key == "arcf/v1/control"
    assert (status["v"], status["type"], status["request_id"]) == (1, "status", "z-get-1")
    assert status["workers"] >= 1 and status["sessions"] == []
    # a start written by hand: acknowledged, with the token that controls the session
    (reply,) = z_get(service, json.dumps({
        "v": 1, "type": "start", "request_id": "z-get-2", "stream_id": "cam1",
        "box": [10, 20, 30, 40], "preset": "bacf"}))
    ack = reply[1]
    assert (ack["type"], ack["request_id"], ack["stream_id"]) == ("ack", "z-get-2", "cam1")
    assert ack["session_id"] and ack["control_token"]
    (reply,) = z_get(service, '{"v": 1, "type": "status_request", "request_id": "z-get-3"}')
    assert [s["session_id"] for s in reply[1]["sessions"]] == [ack["session_id"]]
    # bad JSON and a bad request: an error in JSON, saying what is wrong
    (reply,) = z_get(service, '{"v": 1, "type": "status_request"')
    assert (reply[1]["type"], reply[1]["code"]) == ("error", "malformed_message")
    (reply,) = z_get(service, '{"v": 1, "type": "start", "request_id": "z-get-4"}')
    assert (reply[1]["type"], reply[1]["request_id"]) == ("error", "z-get-4")
    assert "stream_id" in reply[1]["message"]


def test_z_sub_prints_a_sessions_results(service: str) -> None:
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    data = [p.read_bytes() for p in seq.frames[:40]]
    sub = subprocess.Popen(
        _example("z_sub.py", "-k", "arcf/v1/json/streams/cam1/sessions/*/results",
                 endpoint=service),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    printed: list[str] = []
    reader = threading.Thread(target=lambda: printed.extend(sub.stdout or []), daemon=True)
    reader.start()
    try:
        wait_until(lambda: any("Press CTRL-C" in line for line in printed), timeout=60,
                   what="z_sub subscribed")
        with TrackingClient(connect=[service], frame_congestion="block") as station:
            results = station.results("cam1")
            ack = station.start("cam1", seq.init_box, preset="bacf", frame_seq=0)
            got: dict[int, Any] = {}
            for i, frame in enumerate(data):  # bounded: 40 frames, each answered in turn
                station.publish_frame("cam1", data=frame, seq=i)
                r = results.get(timeout=60)
                got[r.frame_seq] = r

            def mirrored() -> list[tuple[str, Any]]:
                return [(m[1], json.loads(m[2])) for line in list(printed)
                        if (m := RECEIVED.match(line.rstrip("\n")))]

            # the mirror starts once z_sub's subscription reached the worker: the last
            # frames' results at least
            wait_until(lambda: any(r["frame_seq"] == len(data) - 1 for _, r in mirrored()),
                       timeout=60, what="z_sub printing the last frame's result")
    finally:
        sub.terminate()
        sub.wait(timeout=30)
    lines = mirrored()
    assert lines and {k for k, _ in lines} == {
        f"arcf/v1/json/streams/cam1/sessions/{ack.session_id}/results"}
    for _, r in lines:  # each printed result is the one the SDK decoded, NaN as null
        sdk = got[r["frame_seq"]]
        assert (r["v"], r["type"], r["session_id"], r["status"]) == (
            1, "result", ack.session_id, sdk.status)
        assert [math.nan if v is None else v for v in r["box"]] == pytest.approx(
            sdk.box, nan_ok=True)
    seqs = [r["frame_seq"] for _, r in lines]
    assert seqs == sorted(set(seqs))  # in order, none twice

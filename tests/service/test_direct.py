"""The direct data path (``--worker-listen``): a station that is a Zenoh peer links to the
worker itself, so frames and results do not cross the router. Shown by freezing the process
that holds the router (SIGSTOP): tracking goes on, bit for bit the library's offline. A stream
nobody tracks is still told so (by the station's publisher token, not its frames)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zenoh")

import arcf
from arcf.client import TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import next_result, wait_for_peers, wait_until

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

#: frames tracked with the router running, then with it frozen
BEFORE, FROZEN = 5, 10


def stopped(pid: int) -> bool:
    """Whether process ``pid`` is stopped by a signal (state T in /proc)."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "T"


def test_frames_and_results_bypass_the_router() -> None:
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    data = [p.read_bytes() for p in seq.frames[:BEFORE + FROZEN]]
    box = tuple(float(v) for v in seq.init_box)
    # a lease far above the frozen spell, so that nobody is declared gone while it lasts
    svc = ServiceProcess("--worker-listen", "tcp/127.0.0.1:0", "--lease-ms", "60000",
                         "--max-stream-fps", "10000", workers=1)
    frozen = False
    try:
        with TrackingClient(connect=[svc.endpoint], mode="peer",
                            frame_congestion="block") as station:
            # the router's gossip tells the station where the worker listens: a direct link
            wait_for_peers(station.session)
            errors = station.errors("nobody")
            station.publish_frame("nobody", data=data[0], seq=0)
            notice = errors.get(timeout=30)
            assert notice.code == "no_session" and notice.stream_id == "nobody"

            results = station.results("cam")
            station.start("cam", box, preset="bacf", frame_seq=0)
            got = []
            for i in range(BEFORE + FROZEN):
                if i == BEFORE:  # the router (and the control plane) stop dead
                    os.kill(svc.pid, signal.SIGSTOP)
                    frozen = True
                    wait_until(lambda: stopped(svc.pid), timeout=30,
                               what="the router's process stopped")
                station.publish_frame("cam", data=data[i], seq=i)
                got.append(next_result(results, i - 1, timeout=60))
            os.kill(svc.pid, signal.SIGCONT)
            frozen = False
    finally:
        if frozen:
            os.kill(svc.pid, signal.SIGCONT)
        assert svc.stop() == 0
    assert [r.frame_seq for r in got] == list(range(BEFORE + FROZEN))
    assert [r.status.value for r in got] == ["initialized"] + ["tracking"] * (len(got) - 1)
    expected = arcf.run_sequence(arcf.create_tracker("bacf"),
                                 (decode_compressed(d) for d in data), box).boxes
    np.testing.assert_allclose([r.box for r in got], expected, atol=1e-9)

"""The Siamese presets and the hybrid in the service: a session picks them like any preset,
the presets reply lists them, and a service whose models folder lacks the networks refuses
them with a clear error and still runs ARCF's. A real service on loopback, real JPEG frames
of boat1."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zenoh")

from arcf.client import ServiceError, TrackingClient
from arcf.eval import load_dataset
from arcf.eval.metrics import overlaps
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.waiting import Arrivals
from arcf.models import models_root
from arcf.schemas import Result

pytestmark = [pytest.mark.integration,
              pytest.mark.skipif(not (models_root() / "nanotrack_v2").is_dir(),
                                 reason="needs ../shared/models")]

FRAMES = 15


@pytest.fixture(scope="module")
def service() -> Iterator[ServiceProcess]:
    svc = ServiceProcess(workers=1)
    yield svc
    assert svc.stop() == 0


@pytest.fixture(scope="module")
def boat() -> tuple[list[bytes], np.ndarray]:
    try:
        (seq,) = load_dataset("uav123_10fps", sequences=["boat1"])
    except Exception:
        pytest.skip("needs boat1 in ../shared/data")
    jpegs = [Path(p).read_bytes() for p in seq.frames[:FRAMES]]
    return jpegs, np.asarray(seq.groundtruth[:FRAMES], float)


def test_sessions_of_the_siamese_presets_and_the_hybrid_track_real_frames(
        service: ServiceProcess, boat: tuple[list[bytes], np.ndarray]) -> None:
    """Three sessions on one stream, one per new preset: every frame answered in order, the
    boxes on the boat, the states and confidences reported."""
    jpegs, gt = boat
    stream = "siamese-" + uuid.uuid4().hex[:8]
    results: Arrivals[Result] = Arrivals(lambda r: (r.session_id, r.frame_seq))
    with TrackingClient(connect=[service.endpoint], frame_congestion="block") as client:
        names = {p.name: p.values for p in client.presets().presets}
        assert {"nanotrack", "vittrack", "arcf-nano", "arcf-h"} <= set(names)
        assert names["nanotrack"] == {} and names["arcf-h"]
        sub = client.results(stream, callback=results)
        box = tuple(float(v) for v in gt[0])
        sessions = {preset: client.start(stream, box, preset=preset).session_id
                    for preset in ("nanotrack", "vittrack", "arcf-nano")}
        for k, jpeg in enumerate(jpegs):
            client.publish_frame(stream, data=jpeg, seq=k)
            results.wait(lambda got, k=k: {
                r.session_id for r in got
                if r.frame_seq == k and r.track_state is not None} >= set(sessions.values()),
                f"frame {k} answered by every session", timeout=60)
        for sid in sessions.values():
            client.stop(sid)
        sub.close()
    for preset, sid in sessions.items():
        mine = [r for r in results.got if r.session_id == sid and r.track_state is not None]
        assert [r.frame_seq for r in mine] == list(range(FRAMES)), preset
        iou = overlaps(np.array([r.box for r in mine]), gt)
        assert np.median(iou) > 0.6, (preset, iou)
        assert all(0.0 <= r.confidence <= 1.0 for r in mine)


def test_a_service_without_the_networks_refuses_them_and_runs_the_rest(
        tmp_path: Path, boat: tuple[list[bytes], np.ndarray]) -> None:
    svc = ServiceProcess("--models-dir", str(tmp_path), workers=1)
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            names = {p.name for p in client.presets().presets}
            assert "nanotrack" not in names and "arcf-nano" not in names and "arcf-h" in names
            with pytest.raises(ServiceError) as refused:
                client.start("s", (10, 10, 40, 40), preset="nanotrack")
            assert refused.value.code == "unknown_preset"
            assert "sha256" in str(refused.value) and str(tmp_path) in str(refused.value)
            ack = client.start("s", tuple(float(v) for v in boat[1][0]), preset="arcf-h")
            client.stop(ack.session_id)
    finally:
        assert svc.stop() == 0

"""Re-acquisition: the probe schedule, and a lost track finding its target again on a real
background, at a bounded number of windows per frame, without changing a track that was never
lost."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
import pytest

import arcf
from arcf.data import data_root
from arcf.errors import InvalidParameterError
from arcf.reacquire import Search
from arcf.state import StateParams, TrackState
from arcf.tracker import ARCFTracker

BOAT1 = data_root() / "uav123_10fps" / "data_seq" / "boat1"
needs_data = pytest.mark.skipif(not BOAT1.is_dir(), reason="needs ../shared/data")


def test_parameters_are_checked() -> None:
    with pytest.raises(InvalidParameterError, match="probes"):
        StateParams(probes=0)
    with pytest.raises(InvalidParameterError, match="search_growth"):
        StateParams(search_growth=-1.0)
    assert arcf.create_tracker("bacf", state={"reacquire": True}).params.state.reacquire


def test_search_starts_where_the_target_was_and_grows_to_the_whole_frame() -> None:
    search = Search(centre=(100.0, 200.0), window=80.0, image_hw=(360, 640), probes=3,
                    growth=0.5)
    # every place of the frame lies within half a pitch of some probe centre
    centres = [p for _, p in search._points]
    assert all(1 <= r <= 360 and 1 <= c <= 640 for r, c in centres)
    grid = np.stack(np.meshgrid(np.arange(1, 361, 7), np.arange(1, 641, 7)), -1).reshape(-1, 2)
    nearest = np.min(np.linalg.norm(grid[:, None] - np.array(centres)[None], axis=2), axis=1)
    assert nearest.max() <= math.hypot(20, 20) + 1e-6  # pitch 40: half a diagonal
    first = search.next_probes()
    assert first[0] == (100.0, 200.0) and len(first) == 3  # where it vanished, first
    seen: set[tuple[float, float]] = set(first)
    for _ in range(search.candidates):
        probes = search.next_probes()
        assert len(probes) <= 3
        # only within the disc of the current frame
        assert all(math.dist(p, (100.0, 200.0)) <= search.radius_px() + 1e-6 for p in probes)
        seen.update(probes)
    assert len(seen) == search.candidates  # the whole frame, eventually


def _iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


@pytest.mark.parametrize("preset", ["arcf-hc", "arcf-h", "bacf"])
def test_a_lost_target_is_found_again_far_from_where_it_vanished(
        preset: str, monkeypatch: pytest.MonkeyPatch,
        hidden_target_scene: Callable[[int], Any]) -> None:
    probes: list[int] = []
    real_probe = ARCFTracker._probe

    def counting_probe(self: ARCFTracker, *args: object) -> object:
        probes[-1] += 1
        return real_probe(self, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(ARCFTracker, "_probe", counting_probe)
    runs = {}
    for reacquire in (False, True):
        tracker = arcf.create_tracker(preset, state={"reacquire": reacquire})
        frame, box = hidden_target_scene(0)
        tracker.init(frame, box)
        results = []
        for k in range(1, 70):
            probes.append(0)
            results.append(tracker.update(hidden_target_scene(k)[0]))
        runs[reacquire] = results
    plain, found = runs[False], runs[True]
    target = hidden_target_scene(69)[1]
    assert target is not None
    # the plain tracker loses it for good, and says so
    assert plain[-1].state is TrackState.LOST and _iou(plain[-1].box, target) == 0
    # with re-acquisition: lost while hidden, found once back, tracking it at the end
    assert any(r.state is TrackState.LOST for r in found[29:39])
    events = [k for k, r in enumerate(found, start=1) if r.reacquired]
    assert events and 40 <= events[0] <= 60, events
    assert found[events[0] - 1].state is TrackState.TRACKING
    assert all(_iou(r.box, hidden_target_scene(k)[1]) > 0.5  # type: ignore[arg-type]
               for k, r in enumerate(found, start=1) if k >= events[0])
    # a bounded number of windows per frame: probes + 1 (the refinement), only while lost
    assert max(probes) <= StateParams().probes + 1
    assert all(n == 0 for n, r in zip(probes[len(plain):], found, strict=True)
               if r.state is not TrackState.LOST and not r.reacquired)
    # identical to the plain tracker until the target vanished
    assert [r.box for r in found[:29]] == [r.box for r in plain[:29]]


@needs_data
def test_a_track_never_lost_is_unchanged() -> None:
    frames = [cv2.imread(str(p)) for p in sorted(BOAT1.glob("*.jpg"))[:25]]
    first_line = (BOAT1.parents[1] / "anno" / "boat1.txt").read_text().splitlines()[0]
    box = tuple(float(v) for v in first_line.split(","))
    boxes = {}
    for reacquire in (False, True):
        tracker = arcf.create_tracker("arcf-h", state={"reacquire": reacquire})
        tracker.init(frames[0], box)
        results = [tracker.update(f) for f in frames[1:]]
        assert all(r.state is TrackState.TRACKING for r in results)
        boxes[reacquire] = [r.box for r in results]
    assert boxes[True] == boxes[False]

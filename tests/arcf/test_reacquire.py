"""Re-acquisition: the template's proposals over the whole frame, and a lost track finding its
target again on a real background, at a bounded number of windows per frame, without changing
a track that was never lost."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import cv2
import pytest

import arcf
from arcf.data import data_root
from arcf.errors import InvalidParameterError
from arcf.reacquire import TargetTemplate
from arcf.state import StateParams, TrackState
from arcf.tracker import ARCFTracker

BOAT1 = data_root() / "uav123_10fps" / "data_seq" / "boat1"
needs_data = pytest.mark.skipif(not BOAT1.is_dir(), reason="needs ../shared/data")


def test_parameters_are_checked() -> None:
    with pytest.raises(InvalidParameterError, match="probes"):
        StateParams(probes=0)
    with pytest.raises(InvalidParameterError, match="reacquire_above"):
        StateParams(reacquire_above=1.5)
    assert arcf.create_tracker("bacf", state={"reacquire": True}).params.state.reacquire


def test_the_template_proposes_the_target_anywhere_in_the_frame(
        hidden_target_scene: Callable[[int], Any]) -> None:
    frame, box = hidden_target_scene(0)
    x, y, w, h = box
    template = TargetTemplate.cut(frame, (y + (h - 1) / 2, x + (w - 1) / 2), (h, w))
    assert template.shrink == pytest.approx(36 / 12) and template.pixels.shape == (12, 12)
    later, (x2, y2, w2, h2) = hidden_target_scene(45)  # back, far from where it was
    proposals = template.candidates(later, 3)
    assert len(proposals) == 3 and proposals[0][0] >= proposals[1][0] >= proposals[2][0]
    _, (row, col) = proposals[0]
    assert math.dist((row, col), (y2 + (h2 - 1) / 2, x2 + (w2 - 1) / 2)) <= 36 / 4
    # apart from each other: no two proposals on the same place
    centres = [c for _, c in proposals]
    assert min(math.dist(a, b) for i, a in enumerate(centres) for b in centres[i + 1:]) >= 12
    assert template.candidates(later[:5, :5], 3) == []  # a frame smaller than the template


@pytest.mark.parametrize("bands", [1, 3, 4, 7])
def test_the_bands_together_search_the_whole_frame_once(
        bands: int, hidden_target_scene: Callable[[int], Any]) -> None:
    """Band by band, every placement of the whole frame's search is matched once, and the
    best of the bands is the whole frame's best, reading only the band's rows."""
    frame, box = hidden_target_scene(0)
    x, y, w, h = box
    template = TargetTemplate.cut(frame, (y + (h - 1) / 2, x + (w - 1) / 2), (h, w))
    later = hidden_target_scene(45)[0]
    k, th = int(template.shrink), template.pixels.shape[0]
    placements = later.shape[0] // k - th + 1
    rows = [template.band(later.shape[:2], i, bands) for i in range(bands)]
    # consecutive placements, each band holding the template at each of its own
    starts = [top // k for top, _ in rows]
    ends = [bottom // k - th + 1 for _, bottom in rows]
    assert starts[0] == 0 and ends[-1] == placements
    assert all(e == s for e, s in zip(ends, starts[1:], strict=False))
    best_whole = template.candidates(later, 1)[0]
    found = []
    for top, bottom in rows:
        masked = later.copy()  # pixels outside the band must not matter
        masked[:top] = 255
        masked[bottom:] = 0
        found += template.candidates(masked, 1, rows=(top, bottom))
    score, centre = max(found)
    assert score == pytest.approx(best_whole[0], abs=1e-4)
    assert math.dist(centre, best_whole[1]) <= 1e-6
    # more bands than placements: some bands are empty, and read nothing
    assert template.band(later.shape[:2], 0, 10 * placements) == (0, 0)
    assert template.candidates(later, 1, rows=(0, 0)) == []


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
    # the plain tracker loses it for good
    assert _iou(plain[-1].box, target) == 0
    # with re-acquisition: lost while hidden, found once back, tracking it at the end
    assert any(r.state is TrackState.LOST for r in found[29:39])
    events = [k for k, r in enumerate(found, start=1) if r.reacquired]
    assert events and 40 <= events[0] <= 60, events
    assert found[events[0] - 1].state is TrackState.TRACKING
    assert all(_iou(r.box, hidden_target_scene(k)[1]) > 0.5  # type: ignore[arg-type]
               for k, r in enumerate(found, start=1) if k >= events[0])
    # the budget: at most ``probes`` windows per frame, only on frames after a lost one
    assert max(probes) == StateParams().probes
    after_lost = [False] + [r.state is TrackState.LOST for r in found[:-1]]
    assert all(n == 0 for n, lost in zip(probes[len(plain):], after_lost, strict=True)
               if not lost)
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

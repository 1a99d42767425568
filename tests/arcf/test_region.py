"""``read_region``: a frame known only inside it gives every preset's results bit for bit.

Each frame is handed over as a ``RegionFrame`` whose pixels outside the tracker's region are
random (a decoder that skipped them leaves whatever the buffer held), and the results are
compared, field by field, with the same preset's on the whole frames. The sequences cover a
tiny target (truck4_1), a lost one searched for band by band (wakeboard7: the search's band
and windows are part of the region, so ``whole()`` is never asked for), and large ones whose
region is the frame.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

import arcf
from arcf.data import default_colornames_path
from arcf.eval.datasets import load_dataset
from arcf.region import RegionFrame, area, clip_region, contains, cover
from arcf.state import TrackState

pytestmark = pytest.mark.slow

CASES = [("uav123_10fps", "truck4_1"), ("uav123_10fps", "wakeboard7"),
         ("dtb70", "MountainBike6")]
FRAMES = 60


def same(a: arcf.TrackResult, b: arcf.TrackResult) -> bool:
    fields = list(vars(a))
    return all(getattr(a, f) == getattr(b, f) or (
        isinstance(getattr(a, f), float) and math.isnan(getattr(a, f))
        and math.isnan(getattr(b, f))) for f in fields)


@pytest.fixture(scope="module")
def sequences() -> dict[str, tuple[list[np.ndarray], tuple[float, ...]]]:
    out = {}
    for dataset, name in CASES:
        try:
            (seq,) = load_dataset(dataset, sequences=[name])
        except (FileNotFoundError, KeyError):
            pytest.skip("needs ../shared/data")
        out[name] = ([cv2.imread(str(p)) for p in seq.frames[:FRAMES]],
                     tuple(float(v) for v in seq.groundtruth[0]))
    return out


#: every preset as shipped, and ARCF-H with its search on (off as shipped)
PRESETS = [("arcf-h", False), ("arcf-h", True), ("arcf-hc", False), ("bacf", False)]


@pytest.mark.parametrize(("preset", "search"), PRESETS)
@pytest.mark.parametrize("name", [n for _, n in CASES])
def test_a_frame_known_only_where_the_tracker_reads_gives_its_results(
        preset: str, search: bool, name: str, sequences: dict) -> None:
    frames, box = sequences[name]
    kw: dict = {"colornames_path": default_colornames_path()} if preset == "arcf-hc" else {}
    if search:
        kw["state.reacquire"] = True
    whole, partial = arcf.create_tracker(preset, **kw), arcf.create_tracker(preset, **kw)
    assert partial.read_region() is None  # before init: the whole frame
    whole.init(frames[0], box)
    partial.init(frames[0], box)
    rng = np.random.default_rng(7)
    asked_whole, shares, lost_shares, lost = 0, [], [], False
    for k, frame in enumerate(frames[1:], 1):
        region = partial.read_region()
        if region is None:
            given: np.ndarray | RegionFrame = frame
        else:
            t, lf, b, r = region
            assert 0 <= t < b <= frame.shape[0] and 0 <= lf < r <= frame.shape[1]
            pixels = rng.integers(0, 256, frame.shape, dtype=np.uint8)
            pixels[t:b, lf:r] = frame[t:b, lf:r]
            (lost_shares if lost else shares).append(
                area(region) / (frame.shape[0] * frame.shape[1]))

            def complete(frame: np.ndarray = frame) -> np.ndarray:
                nonlocal asked_whole
                asked_whole += 1
                return frame

            given = RegionFrame(pixels, region, complete)
        a, b_ = whole.update(frame), partial.update(given)
        assert same(a, b_), f"{preset} {name} frame {k}: {a} != {b_}"
        lost = b_.state is TrackState.LOST
    assert shares, "the tracker never named a region"
    # a lost track's search reads its band and its windows, named before the frame
    assert asked_whole == 0
    if search and name == "wakeboard7":  # the rider is lost and searched for
        assert len(lost_shares) >= 10 and float(np.mean(lost_shares)) < 0.95, lost_shares
    if name == "truck4_1":  # a 11x8 px target: a small part of the frame is read
        assert max(shares) < 0.1


def test_a_region_that_falls_short_gets_the_whole_frame(sequences: dict) -> None:
    frames, box = sequences["truck4_1"]
    whole, partial = arcf.create_tracker("arcf-h"), arcf.create_tracker("arcf-h")
    whole.init(frames[0], box)
    partial.init(frames[0], box)
    asked = []
    for frame in frames[1:6]:
        region = partial.read_region()
        assert region is not None
        short = (region[0] + 40, region[1] + 40, region[2], region[3])
        pixels = np.zeros_like(frame)
        given = RegionFrame(pixels, short, lambda frame=frame: asked.append(1) or frame)
        assert same(whole.update(frame), partial.update(given))
    assert len(asked) == 5


@pytest.mark.parametrize("preset", ["arcf-h", "arcf-hc"])
def test_a_target_that_moves_further_than_the_region_allows_gets_the_whole_frame(
        preset: str, sequences: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    # regions made for a target that barely moves: wakeboard7's moves further on most frames
    monkeypatch.setattr(arcf.tracker, "READ_STEP", 0.01)
    frames, box = sequences["wakeboard7"]
    kw = {"colornames_path": default_colornames_path()} if preset == "arcf-hc" else {}
    whole, partial = arcf.create_tracker(preset, **kw), arcf.create_tracker(preset, **kw)
    whole.init(frames[0], box)
    partial.init(frames[0], box)
    rng = np.random.default_rng(1)
    widened = 0
    for k, frame in enumerate(frames[1:20], 1):
        region = partial.read_region()
        if region is None:
            continue
        t, lf, b, r = region
        pixels = rng.integers(0, 256, frame.shape, dtype=np.uint8)
        pixels[t:b, lf:r] = frame[t:b, lf:r]
        asked: list[int] = []
        given = RegionFrame(pixels, region,
                            lambda frame=frame, asked=asked: asked.append(1) or frame)
        a, b_ = whole.update(frame), partial.update(given)
        assert same(a, b_), f"frame {k}"
        widened += bool(asked) and a.state is TrackState.TRACKING
    assert widened >= 5


@pytest.mark.parametrize("preset", ["nanotrack", "arcf-nano"])
def test_network_presets_read_the_whole_frame(preset: str, sequences: dict) -> None:
    frames, box = sequences["wakeboard7"]
    try:
        whole, partial = arcf.create_tracker(preset), arcf.create_tracker(preset)
    except arcf.ModelNotFoundError:
        pytest.skip("needs ../shared/models")
    whole.init(frames[0], box)
    partial.init(frames[0], box)
    asked = []
    for frame in frames[1:4]:
        assert partial.read_region() is None
        given = RegionFrame(np.zeros_like(frame), (0, 0, 10, 10),
                            lambda frame=frame: asked.append(1) or frame)
        assert same(whole.update(frame), partial.update(given))
    assert len(asked) == 3


def test_region_helpers() -> None:
    assert clip_region(-5.2, 3.5, 10.1, 2000, (100, 200)) == (0, 3, 11, 200)
    assert cover([(0, 0, 5, 5), (3, 4, 10, 6)]) == (0, 0, 10, 6)
    assert cover([(0, 0, 5, 5), None]) is None and cover([]) is None
    assert contains((0, 0, 10, 10), (2, 2, 10, 9)) and not contains((1, 0, 10, 10), (0, 0, 2, 2))

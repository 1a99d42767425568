"""ARCF-H and ARCF-HC on the real sample sequences of the three benchmarks.

Two checks per sequence and tracker, on the first frames of one sequence of each dataset layout:

* against the ground truth: mean centre error and precision at 20 px, with the default presets
  (the paper's aberrance formulation);
* against the authors' own published boxes (``published_results/<dataset>/<ARCF-H|ARCF-HC>``),
  with ``aberrance="release"``: the mode that reproduces the authors' MATLAB release, which is
  what produced those boxes.

Thresholds were set from measured values (noted next to each) with a margin, and each is far
below what a tracker that stops moving scores (the "static" column), so a broken tracker fails.
The data is read from ``arcf.data.data_root()``; tests skip when it is absent.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, lru_cache

import numpy as np
import pytest

import arcf
from arcf.data import data_root, default_colornames_path
from arcf.eval.datasets import load_dataset
from arcf.eval.metrics import center_errors
from arcf.eval.results import read_results

pytestmark = pytest.mark.slow

PRESETS = ("arcf-h", "arcf-hc")


@dataclass(frozen=True)
class Case:
    dataset: str  # loader name
    published: str  # folder under published_results
    name: str
    frames: int  # how many frames from the start are tracked


WAKEBOARD7 = Case("uav123_10fps", "UAV123_10fps", "wakeboard7", 67)  # the whole sequence
MOUNTAINBIKE6 = Case("dtb70", "DTB70", "MountainBike6", 30)
ANIMAL3 = Case("dtb70", "DTB70", "Animal3", 40)
S0310 = Case("uavdt", "UAVDT", "S0310", 40)


def need_data(case: Case) -> None:
    root = data_root() / case.dataset
    if not root.is_dir():
        pytest.skip(f"{case.dataset} sample data not found under {data_root()} (set ARCF_DATA)")
    if not default_colornames_path().is_file():
        pytest.skip(f"Color Names table (ARCF-HC) not found: {default_colornames_path()}")


@lru_cache(maxsize=1)  # one sequence's decoded frames at a time (~180 MB for wakeboard7)
def frames_of(case: Case) -> tuple[tuple[np.ndarray, ...], np.ndarray, tuple[float, ...]]:
    seq = load_dataset(case.dataset, sequences=[case.name])[0]
    n = min(case.frames, len(seq))
    frames = tuple(seq.read_frame(i) for i in range(n))
    return frames, np.array(seq.groundtruth[:n]), seq.init_box


@cache
def track(case: Case, preset: str, aberrance: str = "paper") -> tuple[arcf.TrackResult, ...]:
    frames, _, box = frames_of(case)
    tracker = arcf.create_tracker(preset, aberrance=aberrance)
    return tuple([tracker.init(frames[0], box)] + [tracker.update(f) for f in frames[1:]])


def boxes(results: tuple[arcf.TrackResult, ...]) -> np.ndarray:
    return np.array([r.box for r in results], dtype=np.float64)


def published(case: Case, preset: str, suffix: str = "") -> np.ndarray:
    path = data_root() / "published_results" / case.published / preset.upper()
    path = path / f"{case.name}{suffix}.txt"
    if not path.is_file():
        pytest.skip(f"published result not found: {path}")
    if suffix:
        return np.loadtxt(path)[: case.frames]
    return read_results(path)[: case.frames]


# --------------------------------------------------------------------------- ground truth

# (case, preset) -> (max mean centre error px, min precision@20); measured values in comments.
GT_LIMITS = {
    (WAKEBOARD7, "arcf-h"): (10.0, 0.9),  # mean 4.1, max 9.7, P@20 1.00 (static box: 189 px)
    (WAKEBOARD7, "arcf-hc"): (10.0, 0.9),  # mean 4.6, max 8.8, P@20 1.00
    (MOUNTAINBIKE6, "arcf-h"): (8.0, 0.9),  # mean 2.9, P@20 1.00 (static box: 80 px)
    (MOUNTAINBIKE6, "arcf-hc"): (8.0, 0.9),  # mean 3.0, P@20 1.00
}


@pytest.mark.parametrize(("case", "preset"), list(GT_LIMITS), ids=lambda v: getattr(v, "name", v))
def test_centre_error_against_ground_truth(case: Case, preset: str) -> None:
    need_data(case)
    _, gt, _ = frames_of(case)
    results = track(case, preset)
    assert len(results) == len(gt) == case.frames
    err = center_errors(boxes(results), gt)
    valid = np.isfinite(err)
    mean, p20 = float(err[valid].mean()), float(np.mean(err[valid] <= 20))
    max_mean, min_p20 = GT_LIMITS[case, preset]
    assert mean < max_mean, f"{case.name}/{preset}: mean centre error {mean:.2f} px"
    assert p20 >= min_p20, f"{case.name}/{preset}: precision@20 {p20:.3f}"
    for r in results:
        assert np.all(np.isfinite(r.box)) and np.isfinite(r.peak) and np.isfinite(r.psr)


@pytest.mark.parametrize("preset", PRESETS)
def test_uavdt_no_worse_than_the_authors_run(preset: str) -> None:
    """UAVDT S0310 is hard from the start (the first annotation differs from the second by
    11 px, and every published tracker but ECO-HC drifts), so an absolute 15 px bound would fail
    the authors' own run: compare with it on the same ground truth instead.

    Measured over 40 frames (mean centre error, P@20): ours ARCF-H 23.8 px / 0.45, ARCF-HC
    17.3 px / 0.62; the authors' ARCF-H 23.8 px / 0.42, ARCF-HC 15.8 px / 0.95 (its errors sit
    just under 20 px, ours just over, so P@20 is too brittle to compare); a static box 31.9 px.
    """
    need_data(S0310)
    _, gt, _ = frames_of(S0310)
    ours = center_errors(boxes(track(S0310, preset)), gt)
    theirs = center_errors(published(S0310, preset), gt)
    assert ours.mean() < theirs.mean() + 5.0, (ours.mean(), theirs.mean())
    assert ours.mean() < 28.0, ours.mean()
    assert np.mean(ours <= 30) >= 0.6, np.round(ours, 1)  # measured 0.70 / 1.00; static 0.45


# --------------------------------------------------------------------------- published boxes

# (case, preset) -> max mean centre distance to the authors' boxes (release mode), in px.
PUBLISHED_LIMITS = {
    # measured with the release-faithful sampling, RGB features and fHOG arithmetic
    (WAKEBOARD7, "arcf-h"): 4.0,  # measured 0.70 (one frame 18 px); static box 189
    (WAKEBOARD7, "arcf-hc"): 4.0,  # measured 0.015; static 190
    (MOUNTAINBIKE6, "arcf-h"): 5.0,  # measured 0.41; static 80
    (MOUNTAINBIKE6, "arcf-hc"): 5.0,  # measured 0.20; static 80
    (ANIMAL3, "arcf-h"): 4.0,  # measured 0.49; static 78
    (ANIMAL3, "arcf-hc"): 4.0,  # measured 0.18; static 79
    (S0310, "arcf-h"): 5.0,  # measured 1.3; static 10.6
    (S0310, "arcf-hc"): 6.0,  # measured 2.1 (36 of 40 frames <= 5 px: the 0.9 below); static 17.2
}


@pytest.mark.parametrize(
    ("case", "preset"), list(PUBLISHED_LIMITS), ids=lambda v: getattr(v, "name", v)
)
def test_close_to_the_authors_published_boxes(case: Case, preset: str) -> None:
    need_data(case)
    theirs = published(case, preset)
    ours = boxes(track(case, preset, "release"))
    assert theirs.shape == ours.shape
    d = center_errors(ours, theirs)
    limit = PUBLISHED_LIMITS[case, preset]
    assert d[0] < 1.0  # same initial box
    assert d.mean() < limit, f"{case.name}/{preset}: mean distance {d.mean():.2f} px"
    assert np.mean(d <= 5.0) >= 0.9, f"{case.name}/{preset}: {np.round(d, 1)}"
    # sizes agree too (ARCF-H's 5-scale search and ARCF-HC's scale filter)
    ratio = ours[:, 2:] / theirs[:, 2:]
    assert np.all(np.abs(np.log(ratio)) < np.log(1.25)), np.round(ratio, 2)


def test_release_map_difference_has_the_published_magnitude() -> None:
    """ARCF-H's per-frame map difference in the release form (the largest singular value of the
    element-wise absolute difference, ``norm(abs(D))``) matches the authors' ``map_diff`` file.
    Measured on wakeboard7: ours/theirs median ratio 1.000004 (5 %-95 % of frames 0.74-1.06,
    the spread from frames where the boxes drift apart); the signed difference's spectral norm
    gives a median ratio of 0.67, which the bounds reject."""
    need_data(WAKEBOARD7)
    theirs = published(WAKEBOARD7, "arcf-h", "_map_diff")
    ours = np.array([r.aberrance_release for r in track(WAKEBOARD7, "arcf-h", "release")])
    assert ours.shape == theirs.shape
    assert ours[0] == 0.0 and theirs[0] == 0.0
    ratio = np.median(ours[1:] / theirs[1:])
    assert 0.9 < ratio < 1.1, ratio

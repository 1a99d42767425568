"""Made losses (arcf.eval.losses): what each kind shows, and what its ground truth says."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from arcf.eval.losses import PAN_SLEW, make_loss


def _sequence(folder: Path, n: int = 30, value: int = 0) -> tuple[list[Path], np.ndarray]:
    """``n`` 240 x 320 PNG frames of noise, a white 20 x 20 target moving right by 2 px a
    frame from (60, 100) (1-based x, y), and its ground truth."""
    rng = np.random.default_rng(value)
    folder.mkdir(parents=True)
    paths, gt = [], []
    for k in range(n):
        frame = rng.integers(0, 120, (240, 320, 3), dtype=np.uint8)
        x, y = 60 + 2 * k, 100
        frame[y - 1:y + 19, x - 1:x + 19] = 255
        path = folder / f"{k + 1:06d}.png"
        cv2.imwrite(str(path), frame)
        paths.append(path)
        gt.append((x, y, 20, 20))
    return paths, np.array(gt, float)


def test_a_cover_hides_the_target_where_the_ground_truth_says_nan(tmp_path: Path) -> None:
    paths, gt = _sequence(tmp_path / "s")
    loss = make_loss("cover", "s", paths, gt, 6)
    assert loss is not None and loss.name == "s+cover6"
    assert np.flatnonzero(loss.hidden).tolist() == list(range(15, 21))
    for k, frame in enumerate(loss.frames()):
        x, y = (int(v) for v in gt[k, :2])
        white = frame[y - 1:y + 19, x - 1:x + 19].mean() > 250
        assert white == (not loss.hidden[k]), k
    assert np.array_equal(loss.groundtruth[~loss.hidden], gt[~loss.hidden])


def test_a_cut_shows_the_other_sequence_at_the_frame_size(tmp_path: Path) -> None:
    paths, gt = _sequence(tmp_path / "s")
    other, _ = _sequence(tmp_path / "o", n=4, value=1)
    loss = make_loss("cut", "s", paths, gt, 5, other)
    assert loss is not None
    frames = list(loss.frames())
    assert len(frames) == 30 and {f.shape for f in frames} == {(240, 320, 3)}
    for k in range(15, 20):
        assert loss.hidden[k]
        assert np.array_equal(frames[k], cv2.imread(str(other[(k - 15) % 4])))
    assert np.array_equal(frames[20], cv2.imread(str(paths[20])))
    assert make_loss("cut", "s", paths, gt, 5) is None  # nothing to cut to


def test_a_pan_slews_the_target_out_of_view_and_back(tmp_path: Path) -> None:
    paths, gt = _sequence(tmp_path / "s")
    loss = make_loss("pan", "s", paths, gt, 4)
    assert loss is not None and loss.offsets is not None
    frames = list(loss.frames())
    assert {f.shape for f in frames} == {(120, 160, 3)}  # half the frame on each axis
    hidden = np.flatnonzero(loss.hidden)
    # out of view during the hold, at most the slews around it
    assert set(range(15 + PAN_SLEW, 15 + PAN_SLEW + 4)) <= set(hidden.tolist())
    assert hidden.min() >= 15 and hidden.max() < 15 + 2 * PAN_SLEW + 4
    for k in np.flatnonzero(~loss.hidden):
        # a box in view covers the white target in the view's pixels
        x, y, w, h = loss.groundtruth[k]
        patch = frames[k][int(y) - 1:int(y - 1 + h), int(x) - 1:int(x - 1 + w)]
        assert patch.size and patch.mean() > 250, k
    # before the slew the view follows the target: its box sits near the view's centre
    x, y, w, h = loss.groundtruth[5]
    assert abs(x - 1 + w / 2 - 80) <= 1 and abs(y - 1 + h / 2 - 60) <= 1


@pytest.mark.parametrize("kind", ["cover", "cut", "pan"])
def test_a_sequence_too_short_takes_no_loss(tmp_path: Path, kind: str) -> None:
    paths, gt = _sequence(tmp_path / "s", n=10)
    assert make_loss(kind, "s", paths, gt, 8, paths) is None  # type: ignore[arg-type]

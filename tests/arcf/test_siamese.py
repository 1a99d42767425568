"""The Siamese presets (NanoTrack v2, VitTrack) and the hybrid arcf-nano, run from the network
files in ``../shared/models`` on real sequences."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

import arcf
from arcf.data import data_root
from arcf.eval import load_dataset, load_sequence
from arcf.eval.metrics import overlaps
from arcf.models import NETWORKS, ModelNotFoundError, model_paths, models_root
from arcf.registry import ALL_PRESETS, available_presets, preset_params
from arcf.state import TrackState

pytestmark = pytest.mark.skipif(not (models_root() / "nanotrack_v2").is_dir(),
                                reason="needs ../shared/models")


def _sequence(name: str):  # type: ignore[no-untyped-def]
    if name in ("car14", "person12_2", "group2_1"):
        folder = data_root() / "occlusions" / name
        if not folder.is_dir():
            pytest.skip("needs ../shared/data/occlusions")
        return load_sequence(folder / "img", folder / "groundtruth.txt", name)
    for ds in ("uav123_10fps", "dtb70", "uavdt"):
        try:
            found = [s for s in load_dataset(ds) if s.name == name]
        except Exception:
            continue
        if found:
            return found[0]
    pytest.skip(f"needs {name} in ../shared/data")


def _track(preset: str, name: str, frames: int | None = None) -> tuple[list, np.ndarray]:
    seq = _sequence(name)
    tracker = arcf.create_tracker(preset)
    results = []
    for i, path in enumerate(seq.frames[:frames]):
        frame = cv2.imread(str(path))
        results.append(tracker.init(frame, seq.init_box) if i == 0 else tracker.update(frame))
    return results, np.asarray(seq.groundtruth[:len(results)], float)


@pytest.mark.parametrize("preset", ["nanotrack", "vittrack", "arcf-nano"])
def test_a_preset_follows_a_real_target_in_the_datasets_convention(preset: str) -> None:
    """boat1's first 40 frames: the boxes are 1-based (the first one is the box given) and
    stay on the boat; every result is a full TrackResult."""
    results, gt = _track(preset, "boat1", 40)
    assert results[0].box == tuple(float(v) for v in gt[0])
    boxes = np.array([r.box for r in results])
    iou = overlaps(boxes, gt)
    assert np.median(iou) > 0.6, iou
    assert [r.frame_index for r in results] == list(range(40))
    assert all(0.0 <= r.confidence <= 1.0 for r in results)
    assert all(r.state is TrackState.TRACKING for r in results[:10])
    # a shift of one pixel in the convention would cost this much overlap on a 30-px boat:
    # the centre errors stay within a few pixels of the ground truth's
    errors = np.hypot(*(boxes[:, :2] + boxes[:, 2:] / 2 - gt[:, :2] - gt[:, 2:] / 2).T)
    assert np.median(errors) < 5.0, errors


def test_siamese_results_say_they_have_no_response_map() -> None:
    results, _ = _track("nanotrack", "boat1", 5)
    later = results[1:]
    assert all(math.isnan(r.psr) and math.isnan(r.aberrance) for r in later)
    assert all(0.0 < r.peak <= 1.0 and r.confidence == pytest.approx(r.peak) for r in later)


def test_the_hybrid_flags_a_real_occlusion_and_finds_the_target_again() -> None:
    """group2_1: the person is hidden in frames 24-37 (1-based). NanoTrack alone follows
    someone else to the end; the hybrid leaves ``tracking`` within 3 frames of the first
    hidden one, claims nothing while the person is hidden, and tracks them again (IoU > 0.5)
    within 10 frames of their return, having restarted the network there."""
    tracker = arcf.create_tracker("arcf-nano")
    seq = _sequence("group2_1")
    gt = np.asarray(seq.groundtruth, float)
    hidden = ~np.all(np.isfinite(gt), axis=1)
    first, last = int(np.flatnonzero(hidden)[0]), int(np.flatnonzero(hidden)[-1])
    states, ious = [], []
    for i, path in enumerate(seq.frames):
        frame = cv2.imread(str(path))
        r = tracker.init(frame, seq.init_box) if i == 0 else tracker.update(frame)
        states.append(r.state)
        ious.append(0.0 if hidden[i] else float(overlaps(np.array([r.box]), gt[i:i + 1])[0]))
    assert all(s is TrackState.TRACKING for s in states[:first - 2])
    assert any(s is not TrackState.TRACKING for s in states[first:first + 4])
    flagged = next(i for i in range(first, last + 1) if states[i] is not TrackState.TRACKING)
    assert all(s is not TrackState.TRACKING for s in states[flagged:last + 1])
    back = range(last + 1, min(last + 11, len(states)))
    assert any(states[i] is TrackState.TRACKING and ious[i] > 0.5 for i in back), (
        [(i, states[i].value, round(ious[i], 2)) for i in back])
    assert tracker.restarts >= 1  # type: ignore[attr-defined]
    assert np.mean(ious[last + 11:]) > 0.5


def test_nanotrack_alone_does_not_find_that_target_again() -> None:
    """The same clip without the filter: the network keeps its box on someone else, so the
    hybrid's re-detection above is what finds the person."""
    results, gt = _track("nanotrack", "group2_1")
    after = [float(overlaps(np.array([r.box]), gt[i:i + 1])[0])
             for i, r in enumerate(results) if i >= 38]
    assert max(after) < 0.2


def test_missing_or_altered_network_files_are_refused_with_where_to_get_them(
        tmp_path: Path) -> None:
    with pytest.raises(ModelNotFoundError) as missing:
        arcf.create_tracker("nanotrack", models_dir=tmp_path)
    text = str(missing.value)
    for m in NETWORKS["nanotrack"]:
        assert m.sha256 in text and m.name in text
    assert "HonglinChu/SiamTrackers" in text and "ARCF_MODELS" in text
    altered = tmp_path / "vittrack"
    altered.mkdir()
    (src,) = model_paths("vittrack")
    shutil.copy(src, altered / src.name)
    with (altered / src.name).open("r+b") as f:  # one byte changed, the size kept
        f.seek(1000)
        byte = f.read(1)
        f.seek(1000)
        f.write(bytes([byte[0] ^ 0xFF]))
    with pytest.raises(ModelNotFoundError, match="not the published file"):
        arcf.create_tracker("vittrack", models_dir=tmp_path)
    why = available_presets(tmp_path)
    assert why["arcf-h"] == "" and why["nanotrack"] and why["arcf-nano"] and why["vittrack"]
    # the check a deployment runs (the image's build): an altered file or a half-filled
    # network folder fails, a network not carried only when required
    from arcf.cli import main as cli

    assert cli(["models"]) == 0
    assert cli(["models", "--dir", str(tmp_path)]) == 1  # vittrack altered
    (altered / src.name).unlink()
    assert cli(["models", "--dir", str(tmp_path)]) == 1  # vittrack's folder, without its file
    altered.rmdir()
    assert cli(["models", "--dir", str(tmp_path)]) == 0  # nothing carried, nothing wrong
    assert cli(["models", "--dir", str(tmp_path), "--require", "nanotrack"]) == 1
    half = tmp_path / "nanotrack_v2"  # one of NanoTrack's two files: a half-done copy
    half.mkdir()
    first = model_paths("nanotrack")[0]
    shutil.copy(first, half / first.name)
    assert cli(["models", "--dir", str(tmp_path)]) == 1


def test_the_models_folder_is_a_setting(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ARCF_MODELS", str(tmp_path))
    assert models_root() == tmp_path
    with pytest.raises(ModelNotFoundError, match=str(tmp_path)):
        arcf.create_tracker("arcf-nano")


def test_siamese_presets_take_no_overrides_and_names_are_checked() -> None:
    assert {"nanotrack", "vittrack", "arcf-nano", "arcf-h", "arcf-hc", "bacf"} <= set(
        ALL_PRESETS)
    with pytest.raises(arcf.ARCFError, match="takes no overrides"):
        preset_params("nanotrack", gamma=1.0)
    with pytest.raises(arcf.UnknownPresetError, match="unknown preset"):
        arcf.create_tracker("siamrpn")


def test_bad_input_is_refused_as_for_every_preset() -> None:
    tracker = arcf.create_tracker("nanotrack")
    frame = np.zeros((120, 160, 3), np.uint8)
    with pytest.raises(arcf.NotInitializedError):
        tracker.update(frame)
    with pytest.raises(arcf.InvalidBoxError):
        tracker.init(frame, (500, 500, 10, 10))
    with pytest.raises(arcf.InvalidFrameError):
        tracker.init(frame.astype(np.float32), (10, 10, 20, 20))
    tracker.init(frame[..., 0], (10, 10, 20, 20))  # grey frames are accepted
    with pytest.raises(arcf.InvalidFrameError, match="size changed"):
        tracker.update(np.zeros((100, 160), np.uint8))
    assert tracker.update(frame[..., 0]).frame_index == 1

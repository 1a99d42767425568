"""The OPE runner: files, determinism across processes, resume, failure isolation, progress."""

from __future__ import annotations

import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

import arcf
from arcf.eval import load_sequence, read_results
from arcf.eval.runner import Progress, TrackerSpec, result_dir, run_experiment
from arcf.run import run_sequence


def _make_sequence(root: Path, name: str, n: int = 8, seed: int = 0):
    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur(rng.integers(0, 255, (180, 240, 3), dtype=np.uint8), (0, 0), 4)
    target = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
    folder = root / name / "img"
    folder.mkdir(parents=True)
    rows = []
    for i in range(n):
        frame = bg.copy()
        x, y = 80 + 2 * i, 70 + i
        frame[y : y + 24, x : x + 32] = target
        cv2.imwrite(str(folder / f"{i + 1:04d}.png"), frame)
        rows.append(f"{x + 1},{y + 1},32,24")
    (root / name / "gt.txt").write_text("\n".join(rows) + "\n")
    return load_sequence(folder, root / name / "gt.txt", name=name)


@pytest.fixture()
def sequences(tmp_path: Path):
    return [_make_sequence(tmp_path / "data", f"seq{i}", seed=i) for i in range(2)]


def test_run_writes_every_file_and_matches_an_in_process_run(tmp_path: Path, sequences) -> None:
    spec = TrackerSpec("arcf-h", {"aberrance": "release"})
    assert spec.name == "arcf-h_aberrance-release"
    infos = run_experiment(spec, sequences, tmp_path / "out", jobs=2, progress=False)
    assert sorted(i.sequence for i in infos) == ["seq0", "seq1"]
    folder = result_dir(tmp_path / "out", spec, "generic")
    for seq in sequences:
        boxes = read_results(folder / f"{seq.name}.txt")
        assert boxes.shape == (len(seq), 4)
        times = np.loadtxt(folder / f"{seq.name}_time.txt")
        assert times.shape == (len(seq),) and np.all(times > 0)
        details = np.loadtxt(folder / f"{seq.name}_details.csv", delimiter=",", skiprows=1)
        assert details.shape == (len(seq), 7)
        assert details[0, 2] == 0 and np.all(details[1:, 2] > 0)  # aberrance after frame 1
        assert details[0, 5] == 1.0 and details[0, 6] == 0  # the given box: tracking, sure
        assert np.all((details[:, 5] >= 0) & (details[:, 5] <= 1))
        assert set(details[:, 6]) <= {0, 1, 2}
        # a worker process gives exactly the boxes of the library run here (4-decimal files)
        frames = [seq.read_frame(i) for i in range(len(seq))]
        local = run_sequence(arcf.create_tracker(spec.preset, **spec.overrides), frames,
                             seq.init_box)
        np.testing.assert_allclose(boxes, local.boxes, atol=1e-4)
    fps = json.loads((folder / "fps.json").read_text())
    assert set(fps) == {"seq0", "seq1"} and all(v > 0 for v in fps.values())


def test_run_resumes_without_redoing_finished_sequences(tmp_path: Path, sequences) -> None:
    spec = TrackerSpec("bacf")
    run_experiment(spec, sequences[:1], tmp_path / "out", jobs=1, progress=False)
    done = result_dir(tmp_path / "out", spec, "generic") / "seq0.txt"
    stamp = done.stat().st_mtime_ns
    infos = run_experiment(spec, sequences, tmp_path / "out", jobs=2, progress=False)
    by_name = {i.sequence: i for i in infos}
    assert by_name["seq0"].skipped and not by_name["seq1"].skipped
    assert done.stat().st_mtime_ns == stamp
    fps = json.loads((done.parent / "fps.json").read_text())
    assert set(fps) == {"seq0", "seq1"}  # the resumed run still reports both


def test_a_failing_sequence_does_not_stop_the_others(tmp_path: Path, sequences) -> None:
    bad = sequences[1]
    bad.frames[3].write_bytes(b"not an image")  # a corrupt frame mid-sequence
    spec = TrackerSpec("bacf")
    with pytest.raises(RuntimeError, match="seq1"):
        run_experiment(spec, sequences, tmp_path / "out", jobs=2, progress=False)
    folder = result_dir(tmp_path / "out", spec, "generic")
    assert (folder / "seq0.txt").is_file()
    assert not (folder / "seq1.txt").exists()  # not marked done: a rerun retries it


def test_progress_line_reports_rate_and_eta() -> None:
    out = io.StringIO()
    bar = Progress(100, "arcf-h", stream=out)
    bar.update(25, "seq0 50.0 FPS")
    line = out.getvalue().strip()
    assert line.startswith("arcf-h: 25/100 frames (25%)")
    assert "frames/s" in line and "ETA" in line and "seq0" in line


def test_a_run_folder_scores_with_its_side_files_ignored(tmp_path: Path, sequences) -> None:
    from arcf.eval import score_folder

    spec = TrackerSpec("bacf")
    run_experiment(spec, sequences, tmp_path / "out", jobs=2, progress=False)
    gt = tmp_path / "gt"
    gt.mkdir()
    for seq in sequences:
        np.savetxt(gt / f"{seq.name}.txt", seq.groundtruth, delimiter=",", fmt="%.2f")
    score = score_folder(result_dir(tmp_path / "out", spec, "generic"), gt)
    assert sorted(score.sequences) == ["seq0", "seq1"]  # no "seq0_time", "seq0_map_diff"
    assert score.precision20 == 1.0

"""`arcf track` end to end on a folder of synthetic frames."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from arcf import cli
from arcf.cli import main
from arcf.eval import read_results
from arcf.presets import PRESETS
from arcf.types import TrackResult


def _frames(folder: Path, n: int = 12) -> tuple[float, float, float, float]:
    """A textured 40x30 target drifting right by 2 px per frame over a smooth background."""
    rng = np.random.default_rng(3)
    background = cv2.GaussianBlur(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8), (0, 0), 5)
    target = rng.integers(0, 255, (30, 40, 3), dtype=np.uint8)
    folder.mkdir()
    for i in range(n):
        frame = background.copy()
        x = 100 + 2 * i
        frame[100:130, x : x + 40] = target
        # names that sort wrongly as plain strings: 2.png must come before 10.png
        cv2.imwrite(str(folder / f"{i + 1}.png"), frame)
    return 101.0, 101.0, 40.0, 30.0  # 1-based box of frame 1


def test_track_writes_one_row_per_frame_and_follows_the_target(tmp_path: Path) -> None:
    box = _frames(tmp_path / "frames")
    out, details, overlay = tmp_path / "out.txt", tmp_path / "d.csv", tmp_path / "overlay"
    rc = main([
        "track", str(tmp_path / "frames"), "--box", ",".join(map(str, box)), "--preset", "arcf-h",
        "-o", str(out), "--details", str(details), "--overlay-dir", str(overlay),
    ])
    assert rc == 0
    rows = np.loadtxt(out, delimiter=",")
    assert rows.shape == (12, 4)
    np.testing.assert_allclose(rows[0], box)
    # the target moved 22 px right by the last frame (natural sort order of 1.png..12.png)
    assert rows[-1, 0] == pytest.approx(box[0] + 22, abs=3)
    assert rows[-1, 1] == pytest.approx(box[1], abs=3)
    csv = details.read_text().splitlines()
    assert csv[0].startswith("frame,x,y,w,h,peak,psr,aberrance")
    assert len(csv) == 13
    header = csv[0].split(",")
    first = dict(zip(header, csv[1].split(","), strict=True))
    assert (first["state"], float(first["confidence"])) == ("tracking", 1.0)  # the init frame
    assert all(row.split(",")[header.index("state")] in ("tracking", "coasting", "lost")
               for row in csv[1:])
    assert len(list(overlay.glob("*.jpg"))) == 12


def test_track_init_from_annotation_and_overrides(tmp_path: Path) -> None:
    box = _frames(tmp_path / "frames", n=4)
    anno = tmp_path / "gt.txt"
    anno.write_text(",".join(map(str, box)) + "\n")
    out = tmp_path / "o.txt"
    assert main(["track", str(tmp_path / "frames"), "--init-from", str(anno), "--preset",
                 "bacf", "--set", "admm_iterations=3", "-o", str(out)]) == 0
    assert len(out.read_text().splitlines()) == 4


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--box", "900,900,10,10"], "entirely outside"),
        (["--box", "101,101,40,30", "--set", "gamma=-1"], "gamma must be a finite number in"),
        (["--box", "101,101,40,30", "--set", "gama=1"], "unknown parameter"),
        ([], "give the initial box"),
    ],
)
def test_track_reports_bad_input_clearly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    _frames(tmp_path / "frames", n=2)
    with pytest.raises(SystemExit) as info:
        main(["track", str(tmp_path / "frames"), *args, "-o", str(tmp_path / "o.txt")])
    assert message in str(info.value)


def test_track_rejects_a_folder_without_frames(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="no frames"):
        main(["track", str(tmp_path / "empty"), "--box", "1,1,5,5"])


# ---------------------------------------------------------------- nested (dotted) overrides
def _scenario_frames(folder: Path, scenario: Any) -> str:
    """The re-acquisition scenario as a folder of JPEG files; its first box as --box."""
    folder.mkdir()
    for k, jpeg in enumerate(scenario.jpegs):
        (folder / f"{k + 1:05d}.jpg").write_bytes(jpeg)
    return ",".join(map(str, scenario.init_box))


@pytest.mark.parametrize("reacquire", [False, True])
def test_track_sets_nested_fields_with_dotted_names(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, reacquire_scenario: Any,
        reacquire: bool) -> None:
    """``--set state.reacquire=true`` reaches the tracker: the run re-acquires a target that
    came back far from where it vanished (and with ``state.reacquire=false`` it does not)."""
    box = _scenario_frames(tmp_path / "frames", reacquire_scenario)
    seen: list[tuple[Any, list[TrackResult]]] = []
    real = cli.track_frames

    def spy(tracker: Any, frames: Any, init: Any) -> Iterator[Any]:
        seen.append((tracker.params, []))
        for item in real(tracker, frames, init):
            seen[-1][1].append(item[1])
            yield item

    monkeypatch.setattr(cli, "track_frames", spy)
    out = tmp_path / "o.txt"
    assert main(["track", str(tmp_path / "frames"), "--box", box, "--preset", "arcf-hc",
                 "--set", f"state.reacquire={str(reacquire).lower()}", "--set",
                 "state.probes=3", "-o", str(out)]) == 0
    ((params, results),) = seen
    assert (params.state.reacquire, params.state.probes) == (reacquire, 3)
    preset = PRESETS["arcf-hc"]
    assert params.state.lost_after == preset.state.lost_after  # the other fields: the preset's
    assert params.scale_filter == preset.scale_filter
    rows = np.loadtxt(out, delimiter=",")
    assert rows.shape == (reacquire_scenario.length, 4)
    found = reacquire_scenario.found_back(dict(enumerate(rows)))
    events = reacquire_scenario.reacquisitions(
        (k, r.box, r.reacquired) for k, r in enumerate(results))
    if reacquire:
        assert events, "no result re-acquired the target at its new place"
        assert found  # and the written boxes are there too
    else:
        assert not events and not found


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("state.nope=1", "unknown state parameter(s) ['nope']"),
        ("state.probes=0", "state.probes must be an integer in [1, 16], got 0"),
        ("state.reacquire=maybe", "state.reacquire must be true or false"),
        ("foo.bar=1", "unknown parameter 'foo.bar'"),
        ("state.reacquire.deep=1", "unknown parameter 'state.reacquire.deep'"),
    ],
)
def test_track_refuses_a_bad_nested_field_clearly(
        tmp_path: Path, setting: str, message: str) -> None:
    _frames(tmp_path / "frames", n=2)
    with pytest.raises(SystemExit) as info:
        main(["track", str(tmp_path / "frames"), "--box", "101,101,40,30", "--set", setting,
              "-o", str(tmp_path / "o.txt")])
    assert message in str(info.value)
    assert not (tmp_path / "o.txt").exists()


def test_eval_run_sets_nested_fields_with_dotted_names(
        tmp_path: Path, reacquire_scenario: Any) -> None:
    """``arcf eval run --set state.reacquire=true``: the override reaches the worker process
    that tracks each sequence (a DTB70-layout folder of the scenario's JPEG frames)."""
    data = tmp_path / "data"
    seq = data / "hidden"
    seq.mkdir(parents=True)
    _scenario_frames(seq / "img", reacquire_scenario)
    rows = []
    for k in range(reacquire_scenario.length):
        target = reacquire_scenario.target(k)
        rows.append("NaN,NaN,NaN,NaN" if target is None else ",".join(map(str, target)))
    (seq / "groundtruth_rect.txt").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    assert main(["eval", "run", "--preset", "arcf-h", "--set", "state.reacquire=true",
                 "--set", "state.probes=3", "--dataset", str(data), "--data", str(tmp_path),
                 "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    (folder,) = (p for p in out.iterdir() if p.is_dir())
    assert folder.name == "arcf-h_state.probes-3_state.reacquire-True"
    boxes = read_results(folder / "DTB70" / "hidden.txt")
    assert boxes.shape == (reacquire_scenario.length, 4)
    assert reacquire_scenario.found_back(dict(enumerate(boxes))), \
        "the run never found the target at its new place"


@pytest.mark.parametrize(
    ("setting", "message"),
    [("state.nope=1", "unknown state parameter(s) ['nope']"),
     ("state.probes=0", "state.probes must be an integer in [1, 16], got 0"),
     ("foo.bar=1", "unknown parameter 'foo.bar'")],
)
def test_eval_run_refuses_a_bad_nested_field_before_any_process(
        tmp_path: Path, setting: str, message: str) -> None:
    with pytest.raises(SystemExit) as info:
        main(["eval", "run", "--preset", "arcf-h", "--set", setting, "--dataset",
              str(tmp_path), "--out", str(tmp_path / "out")])
    assert message in str(info.value)
    assert not (tmp_path / "out").exists()

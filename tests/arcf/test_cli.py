"""`arcf track` end to end on a folder of synthetic frames."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from arcf.cli import main


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

"""Dataset loaders on the real sample sequences and on small layouts built in tmp_path."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from arcf.data import data_root
from arcf.eval import (
    DatasetError,
    Sequence,
    list_frames,
    load_dataset,
    load_sequence,
    load_uav123_10fps,
    read_annotation,
)
from arcf.eval.datasets import canonical_dataset_name

ROOT = data_root()


def first_row(path: Path) -> tuple[float, ...]:
    """The file's first row parsed independently of the loader (the files use commas)."""
    return tuple(float(v) for v in path.read_text().splitlines()[0].split(","))


def need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"sample data not found: {path} (set ARCF_DATA)")
    return path


# --------------------------------------------------------------------------- real data

UAV123 = {  # name -> (video, first frame, last frame), from the sequence table
    "boat1": ("boat1", 1, 301),
    "wakeboard7": ("wakeboard7", 1, 67),
    "wakeboard10": ("wakeboard10", 1, 157),
    "truck4_1": ("truck4", 1, 193),
    "truck4_2": ("truck4", 193, 421),
}


def test_uav123_sample_sequences() -> None:
    root = need(ROOT / "uav123_10fps")
    seqs = {s.name: s for s in load_dataset("uav123_10fps")}
    assert set(seqs) == set(UAV123)  # only the videos present locally are listed
    for name, (video, start, end) in UAV123.items():
        s = seqs[name]
        assert s.dataset == "uav123_10fps"
        assert len(s) == end - start + 1 == s.groundtruth.shape[0]
        assert s.frames[0] == root / "data_seq" / video / f"{start:06d}.jpg"
        assert s.frames[-1] == root / "data_seq" / video / f"{end:06d}.jpg"
        assert s.init_box == first_row(root / "anno" / f"{name}.txt")
        assert s.groundtruth.dtype == np.float64


def test_uav123_truck4_1_has_all_193_rows() -> None:
    # `wc -l` reports 192 for this file only because its last row has no newline.
    root = need(ROOT / "uav123_10fps")
    (s,) = load_dataset("UAV123@10fps", sequences=["truck4_1"])
    assert len(s) == 193
    published = need(ROOT / "published_results" / "UAV123_10fps" / "groundtruth")
    np.testing.assert_array_equal(s.groundtruth, read_annotation(published / "truck4_1.txt"))
    assert (root / "anno" / "truck4_1.txt").read_text().count("\n") == 192


def test_uav123_annotations_match_published_groundtruth() -> None:
    published = need(ROOT / "published_results" / "UAV123_10fps" / "groundtruth")
    for s in load_dataset("UAV123_10fps"):
        np.testing.assert_array_equal(s.groundtruth, read_annotation(published / f"{s.name}.txt"))


def test_uav123_read_one_frame() -> None:
    need(ROOT / "uav123_10fps")
    (s,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    image = s.read_frame(0)
    assert image.dtype == np.uint8 and image.shape == (720, 1280, 3)


def test_uav123_filter_errors() -> None:
    need(ROOT / "uav123_10fps")
    with pytest.raises(DatasetError, match=r"unknown sequence.*nope.*available: boat1"):
        load_dataset("uav123_10fps", sequences=["nope"])
    # in the table, but the video is not here
    with pytest.raises(DatasetError, match="bike1 are known but their frames are not"):
        load_dataset("uav123_10fps", sequences=["bike1"])
    # the filter keeps the caller's order
    names = [s.name for s in load_dataset("uav123_10fps", sequences=["truck4_2", "boat1"])]
    assert names == ["truck4_2", "boat1"]


@pytest.mark.parametrize(
    ("name", "n_frames"), [("Animal3", 309), ("BMX3", 121), ("MountainBike6", 81)]
)
def test_dtb70_sample_sequences(name: str, n_frames: int) -> None:
    root = need(ROOT / "dtb70")
    (s,) = load_dataset("DTB70", sequences=[name])
    assert len(s) == n_frames and s.dataset == "dtb70"
    assert s.frames[0] == root / name / "img" / "00001.jpg"
    assert s.frames[-1] == root / name / "img" / f"{n_frames:05d}.jpg"
    assert s.init_box == first_row(root / name / "groundtruth_rect.txt")


def test_dtb70_lists_all_samples() -> None:
    need(ROOT / "dtb70")
    assert [s.name for s in load_dataset("dtb70")] == ["Animal3", "BMX3", "MountainBike6"]


def test_uavdt_sample_sequence() -> None:
    root = need(ROOT / "uavdt")
    (s,) = load_dataset("UAVDT")
    assert s.name == "S0310" and len(s) == 118 and s.dataset == "uavdt"
    assert s.frames[0] == root / "UAV-benchmark-S" / "S0310" / "img000001.jpg"
    assert s.frames[-1].name == "img000118.jpg"
    assert s.init_box == first_row(root / "anno" / "S0310_gt.txt")
    assert s.read_frame(117).ndim == 3


def test_load_dataset_by_path_and_aliases() -> None:
    need(ROOT / "dtb70")
    assert len(load_dataset(ROOT / "dtb70")) == 3
    assert len(load_dataset(str(ROOT / "uavdt"))) == 1
    assert canonical_dataset_name("UAV123@10fps") == "uav123_10fps"
    assert canonical_dataset_name("uav123-10FPS") == "uav123_10fps"
    assert canonical_dataset_name("DTB70") == "dtb70"
    assert canonical_dataset_name("UAVDT") == "uavdt"
    assert canonical_dataset_name("./DTB70") is None  # a path, not the default copy
    with pytest.raises(DatasetError, match="unknown dataset 'otb100'"):
        load_dataset("otb100")


# --------------------------------------------------------------------------- built layouts


def touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


def test_generic_sequence(tmp_path: Path) -> None:
    import cv2

    frames = tmp_path / "frames"
    frames.mkdir()
    for i, name in enumerate(["1.png", "2.png", "10.png"]):  # natural order, not lexicographic
        cv2.imwrite(str(frames / name), np.full((8, 6, 3), 40 * i, np.uint8))
    (frames / "notes.txt").write_text("ignored")
    anno = tmp_path / "gt.txt"
    anno.write_text("1,2,3,4\n2\t3\t4\t5\nNaN NaN NaN NaN")
    s = load_sequence(frames, anno)
    assert isinstance(s, Sequence)
    assert s.name == "frames" and s.dataset == "generic"
    assert [p.name for p in s.frames] == ["1.png", "2.png", "10.png"]
    assert s.init_box == (1.0, 2.0, 3.0, 4.0)
    assert np.isnan(s.groundtruth[2]).all()  # NaN rows are preserved
    assert s.read_frame(2)[0, 0, 0] == 80
    assert len(list_frames(frames)) == 3
    assert not s.groundtruth.flags.writeable


def test_generic_count_mismatch(tmp_path: Path) -> None:
    touch(tmp_path / "f" / "a.jpg")
    touch(tmp_path / "f" / "b.jpg")
    anno = tmp_path / "gt.txt"
    anno.write_text("1,2,3,4\n")
    with pytest.raises(DatasetError, match="2 frames but 1 annotation rows"):
        load_sequence(tmp_path / "f", anno)


def test_undecodable_frame_names_file(tmp_path: Path) -> None:
    bad = tmp_path / "f" / "0001.jpg"
    bad.parent.mkdir()
    bad.write_bytes(b"not a jpeg")
    anno = tmp_path / "gt.txt"
    anno.write_text("1,2,3,4\n")
    s = load_sequence(bad.parent, anno)
    with pytest.raises(DatasetError, match=r"cannot decode frame 0 .*0001\.jpg"):
        s.read_frame(0)


@pytest.mark.parametrize(
    ("text", "line"),
    [("1,2,3,4\n5,6,7,8\n9,10,11\n", 3), ("1,2,3,4\n\n1,2,x,4\n", 3), ("1,2,3,4,5\n", 1)],
)
def test_malformed_annotation_names_file_and_line(tmp_path: Path, text: str, line: int) -> None:
    anno = tmp_path / "broken_gt.txt"
    anno.write_text(text)
    with pytest.raises(DatasetError, match=rf"broken_gt\.txt, line {line}:"):
        read_annotation(anno)


def test_empty_annotation(tmp_path: Path) -> None:
    anno = tmp_path / "empty.txt"
    anno.write_text("\n\n")
    with pytest.raises(DatasetError, match="no boxes"):
        read_annotation(anno)


def make_dtb70(root: Path, name: str, frames: list[int], rows: int) -> None:
    for i in frames:
        touch(root / name / "img" / f"{i:05d}.jpg")
    (root / name / "groundtruth_rect.txt").write_text("1,1,5,5\n" * rows)


def test_missing_frame_is_named(tmp_path: Path) -> None:
    make_dtb70(tmp_path, "Seq", [1, 3], rows=3)
    with pytest.raises(DatasetError, match=r"missing frame file: .*Seq/img/00002\.jpg"):
        load_dataset("dtb70", root=tmp_path)


def test_extra_frames_are_a_mismatch(tmp_path: Path) -> None:
    make_dtb70(tmp_path, "Seq", [1, 2, 3], rows=2)
    with pytest.raises(DatasetError, match="3 frames but 2 annotation rows"):
        load_dataset("dtb70", root=tmp_path)


def test_unknown_sequence_lists_available(tmp_path: Path) -> None:
    make_dtb70(tmp_path, "Alpha", [1], rows=1)
    make_dtb70(tmp_path, "Beta", [1], rows=1)
    with pytest.raises(DatasetError, match=r"unknown sequence.*Gamma.*available: Alpha, Beta"):
        load_dataset("dtb70", root=tmp_path, sequences=["Gamma"])


def make_uav123(
    root: Path, rows: int, frames: int, end: int, table_dir: Path | None = None
) -> Path:
    for i in range(1, frames + 1):
        touch(root / "data_seq" / "vid" / f"{i:06d}.jpg")
    (root / "anno").mkdir(parents=True, exist_ok=True)
    (root / "anno" / "vid_1.txt").write_text("\n".join(["1,1,5,5"] * rows))
    (root / "anno" / "gone.txt").write_text("1,1,5,5\n")
    table = (table_dir or root) / "uav123_10fps_sequences.json"
    table.parent.mkdir(parents=True, exist_ok=True)
    table.write_text(
        json.dumps(
            {
                "dataset": "UAV123@10fps",
                "frame_name_digits": 6,
                "frame_ext": "jpg",
                "sequences": [
                    {"name": "vid_1", "video": "vid", "start_frame": 1, "end_frame": end},
                    {"name": "gone", "video": "gone", "start_frame": 1, "end_frame": 1},
                ],
            }
        )
    )
    return table


def test_uav123_short_annotation_truncates_frames(tmp_path: Path) -> None:
    make_uav123(tmp_path, rows=4, frames=5, end=5)
    with pytest.warns(UserWarning, match="4 rows for frames 1..5"):
        (s,) = load_uav123_10fps(tmp_path)
    assert len(s) == 4 and s.frames[-1].name == "000004.jpg"


def test_uav123_large_mismatch_is_an_error(tmp_path: Path) -> None:
    make_uav123(tmp_path, rows=2, frames=20, end=20)
    with pytest.raises(DatasetError, match="20 frames but 2 annotation rows"):
        load_uav123_10fps(tmp_path)


def test_uav123_missing_frame_and_include_missing(tmp_path: Path) -> None:
    make_uav123(tmp_path, rows=6, frames=5, end=6)
    with pytest.raises(DatasetError, match=r"missing frame file: .*vid/000006\.jpg"):
        load_uav123_10fps(tmp_path)
    with pytest.raises(DatasetError, match=r"frame folder not found: .*gone"):
        load_uav123_10fps(tmp_path, sequences=["gone"], include_missing=True)


def test_uav123_table_argument(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    table = make_uav123(tmp_path / "ds", rows=3, frames=3, end=3, table_dir=tmp_path / "elsewhere")
    monkeypatch.setenv("ARCF_DATA", str(tmp_path / "no-data-root"))
    with pytest.raises(DatasetError, match="pass table="):
        load_uav123_10fps(tmp_path / "ds")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (s,) = load_uav123_10fps(tmp_path / "ds", table=table)
    assert s.name == "vid_1" and len(s) == 3


def test_uavdt_layout(tmp_path: Path) -> None:
    for i in (1, 2):
        touch(tmp_path / "UAV-benchmark-S" / "S9999" / f"img{i:06d}.jpg")
    (tmp_path / "anno").mkdir()
    (tmp_path / "anno" / "S9999_gt.txt").write_text("1,2,3,4\n5,6,7,8\n")
    (s,) = load_dataset("uavdt", root=tmp_path)
    assert s.name == "S9999" and len(s) == 2 and s.init_box == (1.0, 2.0, 3.0, 4.0)
    (tmp_path / "anno" / "S9999_gt.txt").unlink()
    with pytest.raises(DatasetError, match=r"box file not found: .*S9999_gt\.txt"):
        load_dataset(tmp_path)


def test_missing_dataset_root(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="dataset folder not found"):
        load_dataset("dtb70", root=tmp_path / "nowhere")


def test_sequence_validation() -> None:
    with pytest.raises(DatasetError, match="2 frames but 1 ground-truth rows"):
        Sequence("x", (Path("a.jpg"), Path("b.jpg")), np.zeros((1, 4)), "generic")
    with pytest.raises(DatasetError, match="shape"):
        Sequence("x", (Path("a.jpg"),), np.zeros((1, 3)), "generic")

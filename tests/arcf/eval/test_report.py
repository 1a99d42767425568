"""Report pieces: plots written as sane PNGs, Markdown tables, and the paper's Table 2."""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import numpy as np
import pytest

from arcf.data import data_root
from arcf.eval import aggregate, score_sequence
from arcf.eval.metrics import DatasetScore
from arcf.eval.report import (
    legend_labels,
    map_difference_files,
    map_difference_mean,
    markdown_table,
    plot_map_difference,
    plot_precision,
    plot_success,
    ranked,
    read_map_difference,
    table2_markdown,
)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PUBLISHED = data_root() / "published_results"


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from the IHDR chunk, after checking the PNG signature."""
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def fake_score(shift: float, n: int = 40, convention: str = "toolkit") -> DatasetScore:
    """A one-sequence score whose prediction drifts by ``shift`` px per frame (more = worse)."""
    gt = np.tile([50.0, 50.0, 30.0, 30.0], (n, 1))
    pred = gt.copy()
    pred[:, 0] += shift * np.arange(n)
    return aggregate({"seq": score_sequence(pred, gt, convention, name="seq")})  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def many() -> dict[str, DatasetScore]:
    # 13 trackers, more than the 12 colours, with "ours" in the middle of the ranking.
    return {f"T{i:02d}": fake_score(0.2 + 0.15 * i) for i in range(13)}


# --------------------------------------------------------------------------- plots


def test_legend_labels_best_first() -> None:
    scores = {"worse": fake_score(2.0), "best": fake_score(0.0), "mid": fake_score(0.5)}
    names = [n for n, _ in ranked(scores, "precision")]
    assert names == ["best", "mid", "worse"]
    labels = legend_labels(scores, "success")
    assert labels[0] == f"best [{scores['best'].auc:.3f}]"
    assert [lab.split(" [")[0] for lab in labels] == ["best", "mid", "worse"]
    assert labels == sorted(labels, key=lambda s: -float(s.split("[")[1].rstrip("]")))
    assert legend_labels(scores, "precision")[0] == "best [1.000]"
    with pytest.raises(ValueError, match="kind"):
        legend_labels(scores, "speed")  # type: ignore[arg-type]


def test_legend_ties_by_name_and_nan_last() -> None:
    a = fake_score(0.0)
    nan = DatasetScore(
        precision=np.full(51, np.nan),
        success=np.full(21, np.nan),
        precision20=float("nan"),
        auc=float("nan"),
        convention="clean",
    )
    assert legend_labels({"z": a, "none": nan, "a": a}, "precision") == [
        "a [1.000]",
        "z [1.000]",
        "none [n/a]",
    ]


@pytest.mark.parametrize("plot", [plot_precision, plot_success])
def test_plots_write_reasonable_png(plot, many, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    out = plot(many, tmp_path / "sub" / "plot.png", "Thirteen trackers", ours={"T05"})
    assert out == tmp_path / "sub" / "plot.png"
    w, h = png_size(out)
    assert 500 <= w <= 1200 and 350 <= h <= 800  # ~120 dpi, legend beside the axes
    assert 5_000 < out.stat().st_size < 300_000


def test_few_trackers_keep_legend_inside(tmp_path: Path) -> None:
    out = plot_precision({"A": fake_score(0.1), "B": fake_score(1.0)}, tmp_path / "p.png")
    w, h = png_size(out)
    assert 450 <= w <= 700 and 350 <= h <= 550


def test_plot_rejects_bad_input(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no scores"):
        plot_success({}, tmp_path / "x.png")
    bad = DatasetScore(np.zeros(10), np.zeros(21), 0.0, 0.0, "toolkit")
    with pytest.raises(ValueError, match="points"):
        plot_precision({"bad": bad}, tmp_path / "x.png")


def test_missing_matplotlib_says_how_to_install(monkeypatch, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    for mod in ("matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, mod, None)
    with pytest.raises(ImportError, match=r'pip install "arcf\[eval\]"'):
        plot_precision({"A": fake_score(0.0)}, tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_plot_map_difference(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    series = {
        "ARCF-H": np.r_[0.0, rng.uniform(0.005, 0.02, 299)],
        "BACF": np.r_[0.0, rng.uniform(0.005, 0.03, 249), np.nan, rng.uniform(0, 0.03, 9)],
    }
    out = plot_map_difference(series, tmp_path / "md.png", "bike1", ours={"ARCF-H"})
    w, h = png_size(out)
    assert 500 <= w <= 1200 and 250 <= h <= 600
    assert 5_000 < out.stat().st_size < 300_000
    with pytest.raises(ValueError):
        plot_map_difference({}, tmp_path / "none.png")


# --------------------------------------------------------------------------- Markdown table


def test_markdown_table_columns_rows_bold_and_blank_fps() -> None:
    good, mid, bad = fake_score(0.0), fake_score(0.6), fake_score(2.0)
    rows = {
        "ARCF-HC": {"UAV123_10fps": good, "DTB70": mid},
        "BACF": {"UAV123_10fps": mid, "DTB70": good},
        "KCF": {"UAV123_10fps": bad, "DTB70": bad},
        "Partial": {"DTB70": bad},
    }
    fps = {"ARCF-HC": 15.3, "BACF": 52.5, "KCF": None}
    text = markdown_table(rows, fps)
    lines = text.splitlines()
    assert lines[0] == (
        "| Tracker | UAV123_10fps P@20 / AUC | DTB70 P@20 / AUC | Mean P@20 / AUC | FPS |"
    )
    assert lines[1] == "| --- | --- | --- | --- | --- |"
    body = [[c.strip() for c in ln.split("|")[1:-1]] for ln in lines[2:6]]
    assert [r[0] for r in body] == ["ARCF-HC", "BACF", "KCF", "Partial"]
    assert all(len(r) == 5 for r in body)
    g = f"**{good.precision20:.3f}** / **{good.auc:.3f}**"
    m = f"{mid.precision20:.3f} / {mid.auc:.3f}"
    assert body[0][1] == g and body[0][2] == m
    assert body[1][1] == m and body[1][2] == g
    # Equal means print the same, so both are best; a tracker missing a dataset has no mean.
    mean = (
        f"**{(good.precision20 + mid.precision20) / 2:.3f}** / **{(good.auc + mid.auc) / 2:.3f}**"
    )
    assert body[0][3] == body[1][3] == mean
    assert body[3][1] == "—" and body[3][3] == "—"
    assert body[0][4] == "15.3" and body[1][4] == "**52.5**"
    # Unknown FPS (None or absent) is a blank cell.
    assert lines[4].endswith("|  |") and lines[5].endswith("|  |")
    assert "toolkit convention" in text
    bare = markdown_table(rows, fps, note=False).splitlines()
    assert bare == lines[:6] and all(ln.startswith("| ") for ln in bare)


def test_markdown_table_without_fps_and_convention_mix() -> None:
    text = markdown_table({"A": {"D": fake_score(0.0)}}, note=False)
    assert text.splitlines()[2] == "| A | **1.000** / **0.952** | **1.000** / **0.952** |  |"
    with pytest.raises(ValueError, match="convention"):
        markdown_table(
            {"A": {"D": fake_score(0.0)}, "B": {"D": fake_score(0.0, convention="clean")}}
        )
    with pytest.raises(ValueError):
        markdown_table({})


# --------------------------------------------------------------------------- Table 2


def write_lines(path: Path, values: list[str]) -> Path:
    path.write_text("\n".join(values) + "\n", encoding="utf-8")
    return path


def test_map_difference_mean_skips_first_frame_and_nan(tmp_path: Path) -> None:
    # The first values (99, 7) would dominate if they were counted.
    a = write_lines(tmp_path / "a_map_diff.txt", ["99", "1", "NaN", "3"])  # frames 2..n: 1, 3
    b = write_lines(tmp_path / "b_map_diff.txt", ["7", "6"])  # frames 2..n: 6
    c = write_lines(tmp_path / "c_map_diff.txt", ["0", "nan"])  # nothing usable
    assert read_map_difference(a)[0] == 99 and np.isnan(read_map_difference(a)[2])
    assert map_difference_mean([a, b, c]) == pytest.approx((1 + 3 + 6) / 3)
    assert map_difference_mean([a, b, c], "per_sequence") == pytest.approx((2 + 6) / 2)
    assert map_difference_files(tmp_path) == [a, b, c]
    with pytest.raises(ValueError, match="no map-difference"):
        map_difference_mean([c])
    with pytest.raises(ValueError, match="average"):
        map_difference_mean([a], "median")  # type: ignore[arg-type]
    comma = write_lines(tmp_path / "d_map_diff.txt", ["0,2", "4"])
    assert map_difference_mean([comma]) == pytest.approx(3.0)


def test_table2_markdown() -> None:
    text = table2_markdown(
        {
            "ARCF-H": {"UAV123_10fps": 0.010596, "DTB70": 0.0098},
            "BACF": {"UAV123_10fps": 0.013325, "UAVDT": 0.0087},
        }
    )
    assert text.splitlines() == [
        "| Tracker | UAV123_10fps | DTB70 | UAVDT |",
        "| --- | --- | --- | --- |",
        "| ARCF-H | **0.0106** | **0.0098** | — |",
        "| BACF | 0.0133 | — | **0.0087** |",
    ]


@pytest.mark.parametrize(
    ("tracker", "paper", "pooled", "per_sequence"),
    # Measured on the authors' 123 files; only the pooled mean rounds to the paper's Table 2.
    [("ARCF-H", 0.0106, 0.010596, 0.010892), ("BACF", 0.0133, 0.013325, 0.013898)],
)
def test_table2_reproduces_paper_on_uav123(
    tracker: str, paper: float, pooled: float, per_sequence: float
) -> None:
    folder = PUBLISHED / "UAV123_10fps" / tracker
    files = map_difference_files(folder) if folder.is_dir() else []
    if len(files) != 123:
        pytest.skip(f"published map-difference files not found under {folder} (set ARCF_DATA)")
    value = map_difference_mean(files)
    assert round(value, 4) == paper
    assert value == pytest.approx(pooled, abs=5e-7)
    other = map_difference_mean(files, "per_sequence")
    assert other == pytest.approx(per_sequence, abs=5e-7)
    assert round(other, 4) != paper
    row = table2_markdown({tracker: {"UAV123_10fps": value}}).splitlines()[2]
    assert row == f"| {tracker} | **{paper:.4f}** |"

"""Scoring: hand-built cases with values worked out here, and the paper's published figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from arcf.data import data_root
from arcf.eval import (
    PRECISION_THRESHOLDS,
    SUCCESS_THRESHOLDS,
    ResultsError,
    aggregate,
    auc,
    center_errors,
    overlaps,
    precision_curve,
    read_results,
    score_dataset,
    score_folder,
    score_sequence,
    success_curve,
    write_results,
)
from arcf.eval.metrics import precision_at, repair_predictions, valid_groundtruth
from arcf.eval.results import list_result_sequences, read_fps

BOX = (10.0, 10.0, 20.0, 20.0)
# A 20x20 box moved by (3, 4): centre error 5; intersection 17 x 16 = 272 pixels,
# union 400 + 400 - 272 = 528, so IoU = 272 / 528 = 17 / 33 (~0.515, between 0.50 and 0.55).
SHIFTED = (13.0, 14.0, 20.0, 20.0)
SHIFT_IOU = 17.0 / 33.0


def boxes(*rows: tuple[float, float, float, float]) -> np.ndarray:
    return np.array(rows, dtype=np.float64)


def step(values: dict[range, float], n: int) -> np.ndarray:
    """A curve given as value per range of threshold indices."""
    out = np.full(n, np.nan)
    for r, v in values.items():
        out[list(r)] = v
    assert not np.isnan(out).any()
    return out


# --------------------------------------------------------------------------- geometry


def test_thresholds() -> None:
    assert PRECISION_THRESHOLDS.tolist() == list(range(51))
    assert len(SUCCESS_THRESHOLDS) == 21
    assert SUCCESS_THRESHOLDS[0] == 0.0 and SUCCESS_THRESHOLDS[-1] == 1.0
    assert SUCCESS_THRESHOLDS[10] == 0.5 and SUCCESS_THRESHOLDS[6] == 0.3


def test_center_error_uses_inclusive_pixel_centres() -> None:
    # gt spans pixels 1..10 (centre 5.5); pred spans 1..4 (centre 2.5): error 3*sqrt(2).
    err = center_errors(boxes((1, 1, 4, 4)), boxes((1, 1, 10, 10)))
    assert err[0] == pytest.approx(3 * math.sqrt(2))
    assert center_errors(boxes(SHIFTED), boxes(BOX))[0] == pytest.approx(5.0)


def test_overlap_inclusive_pixels_without_plus_one() -> None:
    gt = boxes((1, 1, 10, 10), (1, 1, 10, 10), (1, 1, 10, 10), BOX)
    pred = boxes(
        (6, 1, 10, 10),  # pixels 6..10 shared: 5 x 10 = 50, union 150 -> 1/3
        (11, 1, 10, 10),  # pixels 11..20 touch 1..10 but share none -> 0
        (3, 3, 4, 4),  # inside: 16 / 100
        SHIFTED,
    )
    np.testing.assert_allclose(overlaps(pred, gt), [1 / 3, 0.0, 0.16, SHIFT_IOU])


def test_overlap_degenerate_and_nan() -> None:
    ov = overlaps(boxes((1, 1, 0, 0), (np.nan,) * 4), boxes((1, 1, 0, 0), (1, 1, 5, 5)))
    assert ov[0] == 0.0  # empty union: no overlap rather than 0/0
    assert np.isnan(ov[1])  # no box: left for the convention to decide


def test_curves_boundaries() -> None:
    # Precision counts error <= t, success counts overlap > t.
    p = precision_curve(np.array([20.0]))
    assert p[19] == 0.0 and p[20] == 1.0
    s = success_curve(np.array([0.5]))
    assert s[9] == 1.0 and s[10] == 0.0
    assert precision_curve(np.array([np.nan]))[-1] == 0.0
    assert success_curve(np.array([np.nan]))[0] == 0.0
    assert np.isnan(precision_curve(np.array([]))).all()
    assert auc(np.ones(21)) == 1.0
    assert precision_at(np.arange(51) / 50.0) == pytest.approx(0.4)
    with pytest.raises(ValueError, match="not on the precision curve"):
        precision_at(np.zeros(51), 20.5)


# --------------------------------------------------------------------------- sequences


@pytest.mark.parametrize("convention", ["toolkit", "clean"])
def test_perfect_track(convention: str) -> None:
    gt = boxes(*[(10.0 + i, 20.0 - i, 30.0 + i, 15.0) for i in range(10)])
    s = score_sequence(gt, gt, convention)
    assert (s.precision == 1.0).all()
    # overlap 1 is > every threshold but the last (1.0): 20 of 21 rates are 1.
    np.testing.assert_array_equal(s.success, [1.0] * 20 + [0.0])
    assert s.auc == pytest.approx(20 / 21)
    assert s.precision20 == 1.0
    assert s.n_frames == s.n_scored == 10
    assert (s.errors == 0).all() and (s.overlaps == 1).all()


def test_constant_offset() -> None:
    gt = boxes(*[BOX] * 5)
    pred = boxes(*[SHIFTED] * 5)  # frame 1 is replaced by gt
    s = score_sequence(pred, gt)
    np.testing.assert_allclose(s.errors, [0, 5, 5, 5, 5])
    np.testing.assert_allclose(s.overlaps, [1] + [SHIFT_IOU] * 4)
    # errors <= t: only frame 1 below t = 5
    np.testing.assert_allclose(s.precision, step({range(5): 0.2, range(5, 51): 1.0}, 51))
    # overlaps > t: all five while t <= 0.5 (k <= 10), only frame 1 for 0.55..0.95, none at 1
    expected = step({range(11): 1.0, range(11, 20): 0.2, range(20, 21): 0.0}, 21)
    np.testing.assert_allclose(s.success, expected)
    assert s.auc == pytest.approx((11 * 1.0 + 9 * 0.2) / 21)
    assert s.precision20 == 1.0


def test_empty_overlap() -> None:
    gt = boxes(*[BOX] * 4)
    pred = boxes(*[(500.0, 500.0, 20.0, 20.0)] * 4)
    s = score_sequence(pred, gt)
    np.testing.assert_allclose(s.overlaps, [1, 0, 0, 0])
    np.testing.assert_allclose(s.success, [0.25] * 20 + [0.0])
    assert s.auc == pytest.approx(5 / 21)
    assert s.precision20 == 0.25  # error 490*sqrt(2) on frames 2..4


def test_nan_groundtruth_toolkit_vs_clean() -> None:
    nan = (np.nan,) * 4
    gt = boxes(BOX, BOX, nan, nan, BOX)
    pred = boxes(SHIFTED, SHIFTED, SHIFTED, SHIFTED, SHIFTED)

    tk = score_sequence(pred, gt, "toolkit")
    np.testing.assert_array_equal(tk.valid, [True, True, False, False, True])
    assert tk.n_scored == 5
    # invalid frames are precision hits at every t: 3 of 5 hits below t = 5
    np.testing.assert_allclose(tk.precision, step({range(5): 0.6, range(5, 51): 1.0}, 51))
    # ... and overlap misses: 3 of 5 while t <= 0.5, 1 of 5 up to 0.95
    np.testing.assert_allclose(
        tk.success, step({range(11): 0.6, range(11, 20): 0.2, range(20, 21): 0.0}, 21)
    )
    assert tk.auc == pytest.approx((11 * 0.6 + 9 * 0.2) / 21)
    assert np.isnan(tk.errors[2:4]).all() and np.isnan(tk.overlaps[2:4]).all()

    cl = score_sequence(pred, gt, "clean")
    assert cl.n_scored == 3 and cl.n_frames == 5
    np.testing.assert_allclose(cl.precision, step({range(5): 1 / 3, range(5, 51): 1.0}, 51))
    np.testing.assert_allclose(
        cl.success, step({range(11): 1.0, range(11, 20): 1 / 3, range(20, 21): 0.0}, 21)
    )
    assert cl.auc == pytest.approx((11 + 9 / 3) / 21)


def test_non_positive_groundtruth_validity() -> None:
    # A box touching the top border (y = 0) is invalid for the toolkit (all four must be > 0),
    # a real annotation for the clean convention; a zero-size row is invalid for both.
    gt = boxes(BOX, (5.0, 0.0, 10.0, 10.0), (0.0, 0.0, 0.0, 0.0))
    np.testing.assert_array_equal(valid_groundtruth(gt, "toolkit"), [True, False, False])
    np.testing.assert_array_equal(valid_groundtruth(gt, "clean"), [True, True, False])
    pred = boxes(BOX, (300.0, 300.0, 10.0, 10.0), (300.0, 300.0, 10.0, 10.0))
    assert score_sequence(pred, gt, "toolkit").precision20 == 1.0  # invalid frames are hits
    assert score_sequence(pred, gt, "clean").precision20 == 0.5


@pytest.mark.parametrize("convention", ["toolkit", "clean"])
def test_degenerate_predictions_carried_forward(convention: str) -> None:
    gt = boxes(*[BOX] * 5)
    pred = boxes(
        BOX,
        SHIFTED,
        (np.nan,) * 4,  # no box: frame 2's box is reused
        (50.0, 50.0, 0.0, 12.0),  # zero width: reused again
        (50.0, 50.0, 12.0, -3.0),  # negative height: reused again
    )
    s = score_sequence(pred, gt, convention)
    np.testing.assert_allclose(s.errors, [0, 5, 5, 5, 5])
    np.testing.assert_allclose(s.overlaps, [1] + [SHIFT_IOU] * 4)


def test_partial_nan_prediction_toolkit_is_a_miss() -> None:
    # The toolkit only repairs rows that are entirely NaN (or have a non-positive size), so a
    # row with one NaN survives and scores as a miss; the clean convention repairs it.
    gt = boxes(*[BOX] * 3)
    pred = boxes(BOX, BOX, (np.nan, 10.0, 20.0, 20.0))
    tk = score_sequence(pred, gt, "toolkit")
    assert tk.errors[2] == np.inf and tk.overlaps[2] == 0.0
    assert tk.precision20 == pytest.approx(2 / 3)
    assert score_sequence(pred, gt, "clean").precision20 == 1.0


def test_toolkit_repairs_only_where_gt_has_no_nan() -> None:
    nan = (np.nan,) * 4
    gt = boxes(BOX, BOX, nan, BOX)
    pred = boxes(BOX, SHIFTED, nan, nan)
    # frame 3: gt NaN, so the toolkit leaves the NaN; frame 4 then inherits that NaN
    tk = repair_predictions(pred, gt, "toolkit")
    assert np.isnan(tk[2]).all() and np.isnan(tk[3]).all()
    assert score_sequence(pred, gt, "toolkit").errors[3] == np.inf
    cl = repair_predictions(pred, gt, "clean")
    np.testing.assert_array_equal(cl[2:], [SHIFTED, SHIFTED])


def test_first_frame_replaced_by_groundtruth() -> None:
    gt = boxes(BOX, BOX, BOX)
    pred = boxes((400.0, 400.0, 5.0, 5.0), BOX, BOX)
    s = score_sequence(pred, gt)
    assert s.errors[0] == 0.0 and s.overlaps[0] == 1.0
    assert s.auc == pytest.approx(20 / 21)
    # The toolkit repairs before replacing frame 1, so a degenerate frame 2 inherits the raw
    # frame 1 prediction, not the ground truth.
    pred2 = boxes((400.0, 400.0, 5.0, 5.0), (0.0, 0.0, 0.0, 0.0), BOX)
    repaired = repair_predictions(pred2, gt, "toolkit")
    np.testing.assert_array_equal(repaired, [BOX, (400.0, 400.0, 5.0, 5.0), BOX])


def test_length_mismatch() -> None:
    gt = boxes(*[BOX] * 3)
    longer = boxes(*[BOX] * 5)
    assert score_sequence(longer, gt).n_frames == 3
    with pytest.raises(ValueError, match="2 rows but ground truth has 3"):
        score_sequence(longer[:2], gt)


def test_bad_convention_and_shapes() -> None:
    gt = boxes(BOX)
    with pytest.raises(ValueError, match="unknown convention"):
        score_sequence(gt, gt, "vot")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="shape"):
        score_sequence(np.zeros((3, 3)), np.zeros((3, 3)))


def test_dataset_mean_is_mean_of_sequences() -> None:
    gt = boxes(*[BOX] * 5)
    far = boxes(*[(500.0, 500.0, 20.0, 20.0)] * 5)
    ds = score_dataset({"a": gt, "b": far}, {"a": gt, "b": gt, "c": gt})
    assert set(ds.sequences) == {"a", "b"}
    assert ds.precision20 == pytest.approx((1.0 + 0.2) / 2)
    assert ds.auc == pytest.approx((20 / 21 + 0.2 * 20 / 21) / 2)
    assert ds.convention == "toolkit" and ds.n_sequences == 2
    assert "toolkit convention" in ds.summary()
    with pytest.raises(ValueError, match=r"no ground truth for: x"):
        score_dataset({"x": gt}, {"a": gt})
    with pytest.raises(ValueError, match="different conventions"):
        aggregate({"a": score_sequence(gt, gt, "clean"), "b": score_sequence(gt, gt)})


def test_clean_sequence_without_valid_frames_is_left_out() -> None:
    gt = boxes(*[BOX] * 3)
    empty = boxes(*[(np.nan,) * 4] * 3)
    ds = score_dataset({"a": gt, "b": gt}, {"a": gt, "b": empty}, "clean")
    assert ds.unscored == ("b",) and ds.n_sequences == 1
    assert ds.auc == pytest.approx(20 / 21)


# --------------------------------------------------------------------------- result files


def test_results_roundtrip(tmp_path: Path) -> None:
    arr = boxes((1.23456, 2, 3, 4), (np.nan,) * 4, (10, 20, 30.5, 40.25))
    path = write_results(tmp_path / "sub" / "seq.txt", arr)
    text = path.read_text()
    assert text.splitlines()[0] == "1.2346,2.0000,3.0000,4.0000"
    assert text.splitlines()[1] == "NaN,NaN,NaN,NaN"
    np.testing.assert_allclose(read_results(path), np.round(arr, 4))
    with pytest.raises(ResultsError, match="shape"):
        write_results(tmp_path / "bad.txt", np.zeros((2, 3)))


def test_read_results_separators(tmp_path: Path) -> None:
    p = tmp_path / "r.txt"
    p.write_text("1,2,3,4\n5\t6\t7\t8\r\n9 10  11 12\nnan, NaN ,NAN,nan\n\n")
    got = read_results(p)
    np.testing.assert_array_equal(got[:3], [[1, 2, 3, 4], [5, 6, 7, 8], [9, 10, 11, 12]])
    assert np.isnan(got[3]).all()
    p.write_text("1,2,3,4\n1,2,3\n")
    with pytest.raises(ResultsError, match=r"r\.txt, line 2"):
        read_results(p)


def test_score_folder(tmp_path: Path) -> None:
    res, gt = tmp_path / "tracker", tmp_path / "groundtruth"
    write_results(gt / "a.txt", boxes(*[BOX] * 5))
    write_results(gt / "b.txt", boxes(*[BOX] * 5))
    write_results(gt / "c.txt", boxes(*[BOX] * 5))
    write_results(res / "a.txt", boxes(*[BOX] * 5))
    write_results(res / "b.txt", boxes(*[SHIFTED] * 6))  # one row too many: truncated
    (res / "a_map_diff.txt").write_text("0.1\n0.2\n")  # side file, not boxes
    (res / "fps.json").write_text(json.dumps({"a": 20.5, "b": 30}))

    assert list_result_sequences(res) == ["a", "b"]
    ds = score_folder(res, gt)
    assert sorted(ds.sequences) == ["a", "b"]
    assert ds.sequences["b"].n_frames == 5
    assert ds.precision20 == 1.0
    assert ds.auc == pytest.approx((20 / 21 + (11 + 9 * 0.2) / 21) / 2)
    assert score_folder(res, gt, sequences=["a"]).auc == pytest.approx(20 / 21)
    assert score_folder(res, gt, convention="clean").convention == "clean"
    assert read_fps(res) == {"a": 20.5, "b": 30.0}

    with pytest.raises(ResultsError, match=r"no result in .* for: c"):
        score_folder(res, gt, require_all=True)
    with pytest.raises(ResultsError, match=r"no result file .* for: zzz"):
        score_folder(res, gt, sequences=["zzz"])
    write_results(res / "d.txt", boxes(BOX))
    with pytest.raises(ResultsError, match=r"no ground truth .* for: d"):
        score_folder(res, gt)
    write_results(gt / "d.txt", boxes(BOX, BOX))
    with pytest.raises(ResultsError, match=r"d\.txt: prediction has 1 rows"):
        score_folder(res, gt)


# --------------------------------------------------------------------------- published figures

PUBLISHED = data_root() / "published_results"

# (dataset, convention) -> (precision@20, AUC) of the authors' ARCF-HC boxes, as in
# docs/evaluate.md (toolkit) and the clean figure quoted there for UAV123@10fps.
EXPECTED = {
    ("UAV123_10fps", "toolkit"): (0.666, 0.473),
    ("DTB70", "toolkit"): (0.696, 0.472),
    ("UAVDT", "toolkit"): (0.720, 0.458),
    ("UAV123_10fps", "clean"): (0.647, 0.477),
}
SEQUENCE_COUNTS = {"UAV123_10fps": 123, "DTB70": 70, "UAVDT": 50}


@pytest.mark.parametrize(("dataset", "convention"), sorted(EXPECTED))
def test_reproduces_published_arcf_hc_figures(dataset: str, convention: str) -> None:
    folder = PUBLISHED / dataset
    if not (folder / "ARCF-HC").is_dir() or not (folder / "groundtruth").is_dir():
        pytest.skip(f"published results not found under {folder} (set ARCF_DATA)")
    ds = score_folder(
        folder / "ARCF-HC", folder / "groundtruth", convention=convention, require_all=True
    )
    assert ds.n_sequences == SEQUENCE_COUNTS[dataset]
    precision20, area = EXPECTED[dataset, convention]
    assert abs(round(ds.precision20, 3) - precision20) <= 0.001 + 1e-9
    assert abs(round(ds.auc, 3) - area) <= 0.001 + 1e-9

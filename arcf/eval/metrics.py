"""One-pass-evaluation scores: precision (centre error) and success (overlap) curves.

Two conventions are offered, and every score records which one produced it:

``"toolkit"`` (default)
    What the OTB / UAV123 MATLAB toolkit (``calcSeqErrRobust`` + ``perfPlot``) effectively
    computes, and therefore what every published figure in the ARCF paper used:

    * a ground-truth row is *valid* only if all four values are > 0 (NaN compares false);
    * before anything else, a predicted row that is entirely NaN or has a non-positive width or
      height is replaced by the previous (already repaired) prediction -- but only where the
      ground-truth row has no NaN, because that is how the toolkit's vector ``if`` evaluates;
      a row that survives with a NaN can never be a hit;
    * the first frame's prediction is then replaced by the ground truth;
    * invalid ground-truth frames stay in the denominator, count as precision hits (the toolkit
      stores their error as -1, which is <= every threshold) and as overlap misses (overlap -1 is
      never > a threshold).

``"clean"``
    The same repairs, but any prediction with a NaN or non-positive width/height is carried
    forward, a ground-truth row is valid when it is finite with positive width and height (a box
    touching the image border with ``y = 0`` is a real annotation), and invalid frames are left
    out of both numerator and denominator. It measures tracking only where there is a target.

Geometry follows the toolkit's 1-based inclusive pixel rectangles: a box spans pixels
``x .. x + w - 1``, so its centre is ``(x + (w - 1) / 2, y + (h - 1) / 2)`` and the intersection
width of two boxes is ``min(x1 + w1, x2 + w2) - max(x1, x2)`` (the ``+ 1`` of the inclusive
form cancels the ``- 1``), clipped at 0; areas are ``w * h``.

Precision counts error **<=** t for t = 0..50 px (headline: t = 20); success counts overlap
**>** t for t = 0, 0.05, ..., 1 (headline: AUC, the mean of the 21 rates -- so a perfect
tracker scores 20/21, as the overlap 1 is not > 1). A dataset's figure is the mean over its
sequences of the per-sequence figures.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, overload

import numpy as np

__all__ = [
    "CONVENTIONS",
    "PRECISION_THRESHOLDS",
    "SUCCESS_THRESHOLDS",
    "Convention",
    "DatasetScore",
    "SequenceScore",
    "aggregate",
    "auc",
    "center_errors",
    "centers",
    "overlaps",
    "precision_at",
    "precision_curve",
    "repair_predictions",
    "score_dataset",
    "score_sequence",
    "success_curve",
    "valid_groundtruth",
]

Convention = Literal["toolkit", "clean"]
CONVENTIONS: tuple[str, ...] = ("toolkit", "clean")

#: Centre-error thresholds of the precision plot, in pixels (0, 1, ..., 50).
PRECISION_THRESHOLDS: np.ndarray = np.arange(51, dtype=np.float64)
#: Overlap thresholds of the success plot (0, 0.05, ..., 1), computed as k/20 so that each is
#: the double nearest its decimal value.
SUCCESS_THRESHOLDS: np.ndarray = np.arange(21, dtype=np.float64) / 20.0
PRECISION_THRESHOLDS.setflags(write=False)
SUCCESS_THRESHOLDS.setflags(write=False)


def _boxes(a: np.ndarray | object, what: str) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == 4:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"{what} must be boxes of shape (n, 4) (x, y, w, h); got {arr.shape}")
    return arr


def _check_convention(convention: str) -> None:
    if convention not in CONVENTIONS:
        raise ValueError(f"unknown convention {convention!r}; expected one of {CONVENTIONS}")


# --------------------------------------------------------------------------- per-frame geometry


def centers(boxes: np.ndarray) -> np.ndarray:
    """Box centres ``(x + (w - 1) / 2, y + (h - 1) / 2)`` of 1-based inclusive rectangles."""
    b = _boxes(boxes, "boxes")
    return b[:, :2] + (b[:, 2:] - 1.0) / 2.0


def center_errors(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Euclidean distance between the centres of matching rows (NaN where a row has NaN)."""
    p, g = _boxes(pred, "pred"), _boxes(gt, "gt")
    if p.shape != g.shape:
        raise ValueError(f"pred {p.shape} and gt {g.shape} differ in shape")
    d = centers(p) - centers(g)
    return np.hypot(d[:, 0], d[:, 1])


def overlaps(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """IoU of matching rows, with the toolkit's inclusive-pixel intersection (see module doc).

    Rows whose union is not positive (degenerate boxes on both sides) get 0; NaN inputs give NaN
    so that callers can tell "no box" from "no overlap".
    """
    p, g = _boxes(pred, "pred"), _boxes(gt, "gt")
    if p.shape != g.shape:
        raise ValueError(f"pred {p.shape} and gt {g.shape} differ in shape")
    iw = np.minimum(p[:, 0] + p[:, 2], g[:, 0] + g[:, 2]) - np.maximum(p[:, 0], g[:, 0])
    ih = np.minimum(p[:, 1] + p[:, 3], g[:, 1] + g[:, 3]) - np.maximum(p[:, 1], g[:, 1])
    inter = np.where(np.isnan(iw) | np.isnan(ih), np.nan, np.maximum(iw, 0) * np.maximum(ih, 0))
    union = p[:, 2] * p[:, 3] + g[:, 2] * g[:, 3] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
    iou[np.isnan(union)] = np.nan
    return iou


def valid_groundtruth(gt: np.ndarray, convention: Convention = "toolkit") -> np.ndarray:
    """Which ground-truth rows are scored: toolkit = all four > 0; clean = finite, w > 0, h > 0."""
    _check_convention(convention)
    g = _boxes(gt, "gt")
    with np.errstate(invalid="ignore"):
        if convention == "toolkit":
            return np.all(g > 0, axis=1)
        return np.all(np.isfinite(g), axis=1) & (g[:, 2] > 0) & (g[:, 3] > 0)


def repair_predictions(
    pred: np.ndarray, gt: np.ndarray, convention: Convention = "toolkit"
) -> np.ndarray:
    """The predictions the scores are computed on: degenerate rows carried forward, frame 1 = gt.

    ``pred`` longer than ``gt`` is truncated (the toolkit scores ``size(anno, 1)`` frames); shorter
    is an error, since the missing frames' outcome would have to be invented.
    """
    _check_convention(convention)
    p, g = _boxes(pred, "pred"), _boxes(gt, "gt")
    if p.shape[0] < g.shape[0]:
        raise ValueError(
            f"prediction has {p.shape[0]} rows but ground truth has {g.shape[0]}: "
            "every annotated frame needs a box"
        )
    if g.shape[0] == 0:
        raise ValueError("empty ground truth")
    p = p[: g.shape[0]].copy()
    with np.errstate(invalid="ignore"):
        small = (p[:, 2] <= 0) | (p[:, 3] <= 0)
    if convention == "toolkit":
        # MATLAB: if (isnan(r) | r(3)<=0 | r(4)<=0) & ~isnan(r_anno) -- a vector condition, true
        # only when every element is: an all-NaN row or a non-positive size, and a NaN-free gt.
        degenerate = (np.all(np.isnan(p), axis=1) | small) & ~np.any(np.isnan(g), axis=1)
        first_from_gt = True
    else:
        degenerate = np.any(np.isnan(p), axis=1) | small
        first_from_gt = bool(valid_groundtruth(g[:1], "clean")[0])
    # The toolkit repairs before overwriting frame 1, so frame 2 can inherit the raw frame 1.
    for i in np.flatnonzero(degenerate):
        if i > 0:
            p[i] = p[i - 1]
    if first_from_gt:
        p[0] = g[0]
    return p


# --------------------------------------------------------------------------- curves


def precision_curve(
    errors: np.ndarray, thresholds: np.ndarray = PRECISION_THRESHOLDS
) -> np.ndarray:
    """Fraction of frames whose centre error is <= each threshold (NaN errors are misses).

    An empty input gives NaN rates: there is nothing to be precise about.
    """
    e = np.asarray(errors, dtype=np.float64).ravel()
    t = np.asarray(thresholds, dtype=np.float64)
    if e.size == 0:
        return np.full(t.shape, np.nan)
    return (e[None, :] <= t[:, None]).mean(axis=1)


def success_curve(overlaps: np.ndarray, thresholds: np.ndarray = SUCCESS_THRESHOLDS) -> np.ndarray:
    """Fraction of frames whose overlap is > each threshold (NaN overlaps are misses)."""
    o = np.asarray(overlaps, dtype=np.float64).ravel()
    t = np.asarray(thresholds, dtype=np.float64)
    if o.size == 0:
        return np.full(t.shape, np.nan)
    return (o[None, :] > t[:, None]).mean(axis=1)


def auc(success: np.ndarray) -> float:
    """Area under the success plot as the toolkit reports it: the mean of the success rates."""
    return float(np.mean(success))


def precision_at(
    precision: np.ndarray, threshold: float = 20.0, thresholds: np.ndarray = PRECISION_THRESHOLDS
) -> float:
    """The precision curve's value at ``threshold`` pixels (must be one of ``thresholds``)."""
    idx = np.flatnonzero(np.asarray(thresholds) == threshold)
    if idx.size == 0:
        raise ValueError(f"threshold {threshold} is not on the precision curve")
    return float(np.asarray(precision)[idx[0]])


# --------------------------------------------------------------------------- scores


class Ratio:
    """A score record's figure that is one of its counts over another, NaN when that other is
    0 (no frame to score: unknown, not 0). A descriptor, so that the long-term scores
    (:mod:`arcf.eval.failure`, :mod:`arcf.eval.presence`) declare each such figure in one
    line and share this one rule."""

    def __init__(self, numerator: str, denominator: str) -> None:
        self.numerator, self.denominator = numerator, denominator

    @overload
    def __get__(self, record: None, owner: type | None = None) -> Ratio: ...

    @overload
    def __get__(self, record: object, owner: type | None = None) -> float: ...

    def __get__(self, record: Any, owner: type | None = None) -> Ratio | float:
        if record is None:
            return self
        den = getattr(record, self.denominator)
        return getattr(record, self.numerator) / den if den else float("nan")


@dataclass(frozen=True, eq=False)
class SequenceScore:
    """Scores of one sequence.

    ``errors`` and ``overlaps`` are per frame on the repaired predictions, NaN where the ground
    truth is invalid (``valid`` False) -- the convention decides how those frames count; a
    prediction left NaN gives error ``inf`` and overlap 0. ``n_scored`` is the denominator of the
    curves (all frames for the toolkit, valid ones for the clean convention).
    """

    precision: np.ndarray
    success: np.ndarray
    precision20: float
    auc: float
    n_frames: int
    n_scored: int
    errors: np.ndarray
    overlaps: np.ndarray
    valid: np.ndarray
    convention: str
    name: str = ""


def score_sequence(
    pred: np.ndarray,
    gt: np.ndarray,
    convention: Convention = "toolkit",
    name: str = "",
) -> SequenceScore:
    """Score one sequence's predicted boxes against its ground truth (see module doc)."""
    _check_convention(convention)
    g = _boxes(gt, "gt")
    p = repair_predictions(pred, g, convention)
    valid = valid_groundtruth(g, convention)
    err = center_errors(p, g)
    ov = overlaps(p, g)
    err[valid & np.isnan(err)] = np.inf
    ov[valid & np.isnan(ov)] = 0.0
    err[~valid] = np.nan
    ov[~valid] = np.nan
    if convention == "toolkit":
        # The toolkit's sentinels: -1 is <= every error threshold and > no overlap threshold.
        prec = precision_curve(np.where(valid, err, -1.0))
        succ = success_curve(np.where(valid, ov, -1.0))
        n_scored = g.shape[0]
    else:
        prec = precision_curve(err[valid])
        succ = success_curve(ov[valid])
        n_scored = int(valid.sum())
    for arr in (prec, succ, err, ov, valid):
        arr.setflags(write=False)
    return SequenceScore(
        precision=prec,
        success=succ,
        precision20=precision_at(prec, 20.0),
        auc=auc(succ),
        n_frames=g.shape[0],
        n_scored=n_scored,
        errors=err,
        overlaps=ov,
        valid=valid,
        convention=convention,
        name=name,
    )


@dataclass(frozen=True, eq=False)
class DatasetScore:
    """Mean over sequences of the per-sequence curves and figures.

    Sequences with nothing to score (only possible in the clean convention, when no frame has a
    valid ground truth) are left out of the means and listed in ``unscored``.
    """

    precision: np.ndarray
    success: np.ndarray
    precision20: float
    auc: float
    convention: str
    sequences: dict[str, SequenceScore] = field(default_factory=dict)
    unscored: tuple[str, ...] = ()

    @property
    def n_sequences(self) -> int:
        """How many sequences entered the means."""
        return len(self.sequences) - len(self.unscored)

    def summary(self) -> str:
        """One line naming the convention, as every reported figure should."""
        return (
            f"precision@20 {self.precision20:.3f}  AUC {self.auc:.3f}  "
            f"({self.n_sequences} sequences, {self.convention} convention)"
        )


def aggregate(scores: Mapping[str, SequenceScore]) -> DatasetScore:
    """Average per-sequence scores into a dataset score (all must share one convention)."""
    if not scores:
        raise ValueError("no sequence scores to aggregate")
    conventions = {s.convention for s in scores.values()}
    if len(conventions) != 1:
        raise ValueError(f"cannot average scores of different conventions: {sorted(conventions)}")
    used = {k: s for k, s in scores.items() if s.n_scored > 0}
    unscored = tuple(k for k in scores if k not in used)
    if used:
        prec = np.mean([s.precision for s in used.values()], axis=0)
        succ = np.mean([s.success for s in used.values()], axis=0)
    else:
        prec = np.full(PRECISION_THRESHOLDS.shape, np.nan)
        succ = np.full(SUCCESS_THRESHOLDS.shape, np.nan)
    return DatasetScore(
        precision=prec,
        success=succ,
        # mean of per-sequence figures == figure of the mean curve (both are linear)
        precision20=precision_at(prec, 20.0),
        auc=auc(succ),
        convention=conventions.pop(),
        sequences=dict(scores),
        unscored=unscored,
    )


def score_dataset(
    predictions: Mapping[str, np.ndarray],
    groundtruths: Mapping[str, np.ndarray],
    convention: Convention = "toolkit",
) -> DatasetScore:
    """Score every sequence in ``predictions`` against ``groundtruths`` and average them.

    A prediction without ground truth is an error; ground truth without a prediction is not
    scored (pass exactly the sequences a report covers).
    """
    missing = [k for k in predictions if k not in groundtruths]
    if missing:
        raise ValueError(f"no ground truth for: {', '.join(sorted(missing))}")
    scores = {
        k: score_sequence(predictions[k], groundtruths[k], convention, name=k) for k in predictions
    }
    return aggregate(scores)

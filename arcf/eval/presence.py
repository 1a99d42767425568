"""Target presence, scored as long-term benchmarks score it (VOT-LT, LaSOT's long-term use).

A long-term tracker must say, every frame, whether its target is there. A frame counts as
**reported present** when its state is ``tracking`` (``coasting`` and ``lost`` say: not here,
or not sure). Against the ground truth (a NaN row: the target is not visible), two scores:

* **presence** precision, recall and F-score: a reported frame is right when the target is
  visible and the box overlaps it (IoU > 0, the hit of the confidence model,
  :mod:`arcf.state`); precision = right / reported, recall = right / visible;
* **tracking** precision, recall and F-score (VOT-LT's Pr, Re, F): each reported frame scores
  its IoU (0 where the target is not visible); precision = the IoU summed over reported frames
  / reported frames, recall = the same sum / visible frames. It rewards a good box, not just
  a box on the target.

Frame 0 (the given box) is left out. Sequences pool frame by frame: the counts and sums add
up (VOT-LT averages per sequence instead; on sequences of similar length the two agree).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from .metrics import Ratio, overlaps
from .results import list_result_sequences, read_run


def _f(p: float, r: float) -> float:
    return 2 * p * r / (p + r) if p + r > 0 else 0.0


@dataclass(frozen=True)
class PresenceScore:
    """Presence on one sequence, or pooled (the counts add up)."""

    frames: int
    #: frames with the target visible
    visible: int
    #: frames reported present (state ``tracking``)
    reported: int
    #: reported frames whose box overlaps the visible target
    right: int
    #: IoU summed over the reported frames (0 where the target is not visible)
    overlap: float

    precision = Ratio("right", "reported")
    recall = Ratio("right", "visible")
    #: VOT-LT's Pr and Re: the IoU summed over the reported frames, per reported / visible frame
    tracking_precision = Ratio("overlap", "reported")
    tracking_recall = Ratio("overlap", "visible")

    @property
    def f_score(self) -> float:
        return _f(np.nan_to_num(self.precision), np.nan_to_num(self.recall))

    @property
    def tracking_f(self) -> float:
        return _f(np.nan_to_num(self.tracking_precision), np.nan_to_num(self.tracking_recall))


def score_presence(boxes: np.ndarray, groundtruth: np.ndarray,
                   reported: np.ndarray) -> PresenceScore:
    """One sequence: ``boxes`` and ``groundtruth`` ``(N, 4)``, ``reported`` ``(N,)`` (True where
    the state was ``tracking``); frame 0 left out."""
    boxes = np.asarray(boxes, dtype=np.float64)[1:]
    gt = np.asarray(groundtruth, dtype=np.float64)[1:]
    reported = np.asarray(reported, dtype=bool)[1:]
    if not (len(boxes) == len(gt) == len(reported)):
        raise ValueError(f"{len(boxes)} boxes, {len(gt)} ground-truth rows and {len(reported)}"
                         " states differ")
    with np.errstate(invalid="ignore"):
        visible = np.all(np.isfinite(gt), axis=1) & np.all(gt[:, 2:] > 0, axis=1)
    iou = np.nan_to_num(overlaps(boxes, np.where(visible[:, None], gt, 1.0)), nan=0.0)
    iou[~visible] = 0.0
    return PresenceScore(frames=len(gt), visible=int(visible.sum()),
                         reported=int(reported.sum()), right=int((reported & (iou > 0)).sum()),
                         overlap=float(iou[reported].sum()))


def pool(scores: Iterable[PresenceScore]) -> PresenceScore:
    """Several sequences, frame by frame."""
    scores = list(scores)
    if not scores:
        raise ValueError("nothing to pool")
    return PresenceScore(*(sum(getattr(s, k) for s in scores)
                           for k in ("frames", "visible", "reported", "right", "overlap")))


def score_folder_presence(results_dir: str | os.PathLike[str],
                          groundtruth_dir: str | os.PathLike[str],
                          sequences: Iterable[str] | None = None) -> dict[str, PresenceScore]:
    """Presence of an ``arcf eval run`` folder: boxes from ``<sequence>.txt``, states from the
    ``state`` column of ``<sequence>_details.csv``."""
    names = list(sequences) if sequences is not None else list_result_sequences(results_dir)
    out = {}
    for name in names:
        boxes, gt, details = read_run(results_dir, groundtruth_dir, name)
        out[name] = score_presence(boxes, gt, details["state"] == 0)
    return out

"""Failure detection: how well a tracker's own flags (``lost`` / ``coasting``) say when it has
failed, scored against the ground truth.

A frame is a **failure** when the tracker's box does not overlap the target at all (IoU = 0) or
the target is not visible (a NaN row of the annotation: the box cannot be right). A frame is
**good tracking** when IoU > 0.5. Frames in between are neither: a drifting box is not yet a
failure, and flagging it is no false alarm.

The scores, per sequence and pooled over sequences:

* ``recall_at`` (delay *k*, default 3): the share of failure frames flagged at that frame or
  within the *k* frames after it (while the failure lasts); a detector that needs *k* frames to
  notice a failure is not penalised for them.
* ``onset_delay``: per failure episode (a maximal run of failure frames), frames from its onset
  to its first flag; episodes never flagged are counted apart (``missed_episodes``).
* ``false_alarms_per_1000``: flagged frames per 1,000 frames of good tracking.
* ``precision``: the share of flagged frames that are failures.

``pr_curve`` sweeps a threshold over a per-frame failure score for the whole
precision-recall curve.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from .metrics import Ratio, overlaps
from .results import list_result_sequences, read_run

#: frames of delay a flag may take and still catch a failure frame (issue 16's criterion)
DEFAULT_DELAY = 3
#: IoU above which a frame is good tracking (a flag there is a false alarm)
GOOD_IOU = 0.5


def failure_frames(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(failure, good) masks of a sequence's frames from the predicted and true boxes,
    ``(N, 4)`` each. A NaN (or non-positive) ground-truth row is a failure: no box can be
    right where no target is visible."""
    gt = np.asarray(gt, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        absent = ~np.all(np.isfinite(gt), axis=1) | np.any(gt[:, 2:] <= 0, axis=1)
    iou = overlaps(np.asarray(pred, dtype=np.float64), np.where(absent[:, None], 1.0, gt))
    iou = np.nan_to_num(iou, nan=0.0)
    failure = absent | (iou <= 0.0)
    good = ~absent & (iou > GOOD_IOU)
    return failure, good


def episodes(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True as ``(start, stop)`` (stop exclusive)."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


@dataclass(frozen=True)
class FailureScore:
    """Failure detection on one sequence (or pooled: the counts add up)."""

    frames: int
    failure_frames: int
    good_frames: int
    flagged: int
    #: failure frames caught within the delay (see ``recall_at``)
    caught: int
    flagged_failures: int
    false_alarms: int
    episodes: int
    missed_episodes: int
    #: onset-to-first-flag delays of the episodes that were flagged, frames
    delays: tuple[int, ...]
    delay: int = DEFAULT_DELAY

    recall_at = Ratio("caught", "failure_frames")
    precision = Ratio("flagged_failures", "flagged")

    @property
    def false_alarms_per_1000(self) -> float:
        return 1000.0 * self.false_alarms / self.good_frames if self.good_frames else 0.0

    @property
    def median_delay(self) -> float:
        return float(np.median(self.delays)) if self.delays else float("nan")


def score_flags(flags: np.ndarray, failure: np.ndarray, good: np.ndarray,
                delay: int = DEFAULT_DELAY) -> FailureScore:
    """Score one sequence's per-frame flags (True: the tracker says lost or coasting)."""
    flags = np.asarray(flags, dtype=bool)
    failure = np.asarray(failure, dtype=bool)
    good = np.asarray(good, dtype=bool)
    if not (flags.shape == failure.shape == good.shape):
        raise ValueError(f"flags {flags.shape}, failure {failure.shape} and good {good.shape} "
                         "differ in shape")
    caught, delays, missed = 0, [], 0
    runs = episodes(failure)
    for start, stop in runs:
        f = flags[start:stop]
        hits = np.flatnonzero(f)
        if hits.size == 0:
            missed += 1
        else:
            delays.append(int(hits[0]))
        # frame t is caught if a flag is up at some t' in [t, t + delay] within the episode:
        # a running count of flags from the end
        ahead = np.zeros(stop - start + 1, dtype=np.int64)
        ahead[:-1] = np.cumsum(f[::-1])[::-1]
        idx = np.arange(stop - start)
        window_end = np.minimum(idx + delay + 1, stop - start)
        caught += int(np.count_nonzero(ahead[idx] - ahead[window_end] > 0))
    return FailureScore(
        frames=int(flags.size), failure_frames=int(failure.sum()), good_frames=int(good.sum()),
        flagged=int(flags.sum()), caught=caught,
        flagged_failures=int((flags & failure).sum()), false_alarms=int((flags & good).sum()),
        episodes=len(runs), missed_episodes=missed, delays=tuple(delays), delay=delay)


def pool(scores: Iterable[FailureScore]) -> FailureScore:
    """Scores of several sequences pooled frame by frame (each frame weighs the same)."""
    scores = list(scores)
    if not scores:
        raise ValueError("nothing to pool")
    delay = scores[0].delay
    if any(s.delay != delay for s in scores):
        raise ValueError("scores with different delays cannot be pooled")
    total = {name: sum(getattr(s, name) for s in scores) for name in (
        "frames", "failure_frames", "good_frames", "flagged", "caught", "flagged_failures",
        "false_alarms", "episodes", "missed_episodes")}
    return FailureScore(**total, delays=tuple(d for s in scores for d in s.delays), delay=delay)


@dataclass(frozen=True)
class CurvePoint:
    threshold: float
    recall_at: float
    precision: float
    false_alarms_per_1000: float


def pr_curve(score: Mapping[str, np.ndarray], failure: Mapping[str, np.ndarray],
             good: Mapping[str, np.ndarray], thresholds: Iterable[float],
             delay: int = DEFAULT_DELAY) -> list[CurvePoint]:
    """The precision-recall curve of flagging ``score >= threshold`` (a per-frame failure
    score, e.g. 1 - confidence), pooled over the sequences of the mappings."""
    points = []
    for t in thresholds:
        pooled = pool(score_flags(score[k] >= t, failure[k], good[k], delay) for k in score)
        points.append(CurvePoint(float(t), pooled.recall_at, pooled.precision,
                                 pooled.false_alarms_per_1000))
    return points


@dataclass(frozen=True)
class SequenceFailures:
    """A run's failure detection on one sequence, read from its result folder."""

    score: FailureScore
    failure: np.ndarray
    good: np.ndarray
    #: the tracker's per-frame confidence (NaN where the run did not record one)
    confidence: np.ndarray


def score_folder_failures(results_dir: str | os.PathLike[str],
                          groundtruth_dir: str | os.PathLike[str],
                          sequences: Iterable[str] | None = None,
                          delay: int = DEFAULT_DELAY) -> dict[str, SequenceFailures]:
    """Failure detection of an ``arcf eval run`` folder: each sequence's boxes against its
    ground truth, its flags from the ``state`` column of ``<sequence>_details.csv`` (frame 0,
    the given box, is left out)."""
    names = list(sequences) if sequences is not None else list_result_sequences(results_dir)
    out = {}
    for name in names:
        boxes, gt, details = read_run(results_dir, groundtruth_dir, name)
        failure, good = failure_frames(boxes, gt)
        flags = details["state"] != 0
        conf = details["confidence"]
        out[name] = SequenceFailures(
            score_flags(flags[1:], failure[1:], good[1:], delay), failure[1:], good[1:],
            conf[1:])
    return out

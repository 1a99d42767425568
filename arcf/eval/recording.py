"""Re-scoring a recording: the results an ``arcf-record`` MCAP file holds, against a ground
truth, as ``arcf eval score`` scores a run.

A recording keeps every ``result`` message of a stream on ``/arcf/<stream>/results`` (JSON);
a session's box for frame ``k`` (its ``frame_seq``) is scored against line ``k + 1`` of the
ground-truth file, so a stream numbered from 0 in the dataset's frame order scores exactly as
the library's run on the same frames would. Frames the session has no box for (not tracked:
skipped under load, an error, after it ended) count as misses, the toolkit's convention for a
missing prediction. A session's notices about no frame (``stopped``, ``stale``), which repeat
its last frame's number, are not about that frame and are left out.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .datasets import read_boxes
from .metrics import Convention, SequenceScore, score_sequence


@dataclass(frozen=True)
class RecordedSession:
    session_id: str
    stream_id: str
    #: (n, 4) boxes by frame number (NaN: no box for that frame), n = last frame_seq + 1
    boxes: np.ndarray
    results: int
    tracked: int


def read_recording(paths: Iterable[str | Path]) -> dict[str, RecordedSession]:
    """Every session's boxes in the recording's files (segments in any order)."""
    from mcap.reader import make_reader

    by_session: dict[str, dict[int, list[float] | None]] = {}
    streams: dict[str, str] = {}
    for path in paths:
        with open(path, "rb") as f:
            for _schema, channel, message in make_reader(f).iter_messages():
                if not channel.topic.endswith("/results") or channel.message_encoding != "json":
                    continue
                r = json.loads(message.data)
                if r["status"] in ("stopped", "stale"):
                    continue  # about no frame: its frame_seq is the last frame's, not a miss
                boxes = by_session.setdefault(r["session_id"], {})
                streams[r["session_id"]] = r["stream_id"]
                tracked = r["status"] in ("initialized", "reinitialized", "resumed", "tracking")
                box = r.get("box")
                boxes[int(r["frame_seq"])] = (
                    box if tracked and box and all(v is not None for v in box) else None)
    out = {}
    for sid, boxes in by_session.items():
        n = max(boxes) + 1
        arr = np.full((n, 4), np.nan)
        for k, box in boxes.items():
            if box is not None:
                arr[k] = box
        out[sid] = RecordedSession(sid, streams[sid], arr, len(boxes),
                                   sum(b is not None for b in boxes.values()))
    return out


def score_recording(paths: Iterable[str | Path], groundtruth: str | Path,
                    session: str | None = None, convention: Convention = "toolkit"
                    ) -> dict[str, SequenceScore]:
    """Each session's (or ``session``'s) score against the ground-truth file."""
    gt = read_boxes(groundtruth)
    sessions = read_recording(paths)
    if session is not None:
        if session not in sessions:
            raise ValueError(f"no results of session {session!r} in the recording "
                             f"(it holds {', '.join(sorted(sessions)) or 'none'})")
        sessions = {session: sessions[session]}
    scores = {}
    for sid, rec in sessions.items():
        if rec.boxes.shape[0] > gt.shape[0]:
            raise ValueError(f"session {sid} has results up to frame {rec.boxes.shape[0] - 1}, "
                             f"the ground truth {gt.shape[0]} lines")
        pred = np.full_like(gt, np.nan, dtype=float)
        pred[: rec.boxes.shape[0]] = rec.boxes
        scores[sid] = score_sequence(pred, gt, convention, name=sid)
    return scores

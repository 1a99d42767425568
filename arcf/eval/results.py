"""Result files (one ``x,y,w,h`` row per frame) and scoring a whole folder of them.

The format is the one the published trackers' boxes come in (and that the MATLAB toolkits read
with ``dlmread``), so our tracker's output can be scored by the same code as theirs and compared
row for row.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from arcf.eval.datasets import read_boxes
from arcf.eval.metrics import Convention, DatasetScore, aggregate, score_sequence

__all__ = [
    "AUXILIARY_SUFFIXES",
    "ResultsError",
    "list_result_sequences",
    "read_fps",
    "read_results",
    "read_run",
    "score_folder",
    "write_results",
]

#: Stems ending like this are per-sequence side files, not boxes (the authors' UAV123 folders
#: hold ``<sequence>_map_diff.txt``, the per-frame response-map differences of Eq. 2).
#: Side files beside the box files: the published ``_map_diff`` and our runner's per-frame
#: ``_time`` files (``_details`` is a .csv and never matches ``*.txt``).
AUXILIARY_SUFFIXES: tuple[str, ...] = ("_map_diff", "_time")


class ResultsError(ValueError):
    """A result folder or file cannot be read or does not match the ground truth."""


def read_results(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a result file as an ``(n, 4)`` float64 array (commas, tabs or spaces; NaN allowed)."""
    return read_boxes(path, ResultsError)


def read_run(results_dir: str | os.PathLike[str], groundtruth_dir: str | os.PathLike[str],
             name: str) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """One sequence of an ``arcf eval run`` folder: its boxes ``(N, 4)``, its ground truth
    ``(N, 4)`` and the per-frame columns of ``<sequence>_details.csv`` (``state``,
    ``confidence``, ...), each ``(N,)``; a :class:`ResultsError` when a file is missing, has no
    ``state`` column (a run from before the track state existed) or the lengths differ."""
    folder = Path(results_dir)
    path = folder / f"{name}_details.csv"
    if not path.is_file():
        raise ResultsError(f"{path} not found (runs of arcf eval run write it)")
    with path.open(encoding="utf-8") as f:
        header = f.readline().lstrip("# ").strip().split(",")
    if "state" not in header:
        raise ResultsError(f"{path} has no state column (a run before the track state "
                           "existed: run it again)")
    details = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    boxes = read_results(folder / f"{name}.txt")
    gt = read_results(Path(groundtruth_dir) / f"{name}.txt")
    if not (len(boxes) == len(gt) == len(details)):
        raise ResultsError(f"{name}: {len(boxes)} boxes, {len(gt)} ground-truth rows and "
                           f"{len(details)} detail rows differ")
    return boxes, gt, {k: details[:, i] for i, k in enumerate(header)}


def write_results(
    path: str | os.PathLike[str], boxes: np.ndarray | Iterable[Iterable[float]], precision: int = 4
) -> Path:
    """Write boxes as comma-separated ``x,y,w,h`` rows with ``precision`` decimals.

    Four decimals keep sub-pixel positions (the scores change by far less than their rounding)
    while staying readable; NaN is written as ``NaN``, which both our reader and MATLAB's
    ``dlmread`` accept. Parent folders are created. Returns the path written.
    """
    arr = np.asarray(boxes, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ResultsError(f"boxes must have shape (n, 4); got {arr.shape}")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [",".join("NaN" if np.isnan(v) else f"{v:.{precision}f}" for v in row) for row in arr]
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out


def read_fps(results_dir: str | os.PathLike[str]) -> dict[str, float]:
    """The ``fps.json`` of a result folder (sequence -> frames per second), or {} if absent."""
    path = Path(results_dir) / "fps.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return {str(k): float(v) for k, v in data.items()}
    except (json.JSONDecodeError, AttributeError, TypeError, ValueError) as exc:
        raise ResultsError(f"{path}: not a mapping of sequence to fps ({exc!r})") from None


def list_result_sequences(results_dir: str | os.PathLike[str]) -> list[str]:
    """Sequence names with a ``<name>.txt`` in a result folder, side files excluded, sorted."""
    folder = Path(results_dir)
    if not folder.is_dir():
        raise ResultsError(f"results folder not found: {folder}")
    return sorted(
        p.stem
        for p in folder.glob("*.txt")
        if p.is_file() and not p.stem.endswith(AUXILIARY_SUFFIXES)
    )


def score_folder(
    results_dir: str | os.PathLike[str],
    groundtruth_dir: str | os.PathLike[str],
    sequences: Iterable[str] | None = None,
    convention: Convention = "toolkit",
    require_all: bool = False,
) -> DatasetScore:
    """Score each ``<results_dir>/<seq>.txt`` against ``<groundtruth_dir>/<seq>.txt``.

    ``sequences`` restricts (and requires) the named sequences; by default every result file is
    scored and a result without ground truth is an error (it would otherwise vanish from the
    mean unnoticed). ``require_all=True`` also demands a result for every ground-truth file, as a
    full-benchmark figure must. Returns per-sequence scores (``.sequences``) and their mean.
    """
    res_dir, gt_dir = Path(results_dir), Path(groundtruth_dir)
    if not gt_dir.is_dir():
        raise ResultsError(f"ground-truth folder not found: {gt_dir}")
    present = list_result_sequences(res_dir)
    if sequences is None:
        names = present
    else:
        names = [sequences] if isinstance(sequences, str) else list(dict.fromkeys(sequences))
        absent = [n for n in names if n not in set(present)]
        if absent:
            raise ResultsError(f"no result file in {res_dir} for: {', '.join(absent)}")
    if not names:
        raise ResultsError(f"no result files (*.txt) in {res_dir}")
    no_gt = [n for n in names if not (gt_dir / f"{n}.txt").is_file()]
    if no_gt:
        raise ResultsError(f"no ground truth in {gt_dir} for: {', '.join(no_gt)}")
    if require_all:
        unrun = sorted(set(list_result_sequences(gt_dir)) - set(names))
        if unrun:
            raise ResultsError(f"no result in {res_dir} for: {', '.join(unrun)}")
    scores = {}
    for name in names:
        pred = read_results(res_dir / f"{name}.txt")
        gt = read_boxes(gt_dir / f"{name}.txt", ResultsError)
        try:
            scores[name] = score_sequence(pred, gt, convention, name=name)
        except ValueError as exc:
            raise ResultsError(f"{res_dir / name}.txt: {exc}") from None
    return aggregate(scores)

"""Evaluation toolkit: dataset loaders, OPE precision/success scoring, result files.

Scores default to the OTB/UAV123 MATLAB toolkit's convention, which the published figures use;
``convention="clean"`` leaves frames without a valid ground truth out instead.
"""

from arcf.eval.datasets import (
    DatasetError,
    Sequence,
    list_frames,
    load_dataset,
    load_dtb70,
    load_sequence,
    load_uav123_10fps,
    load_uavdt,
    read_annotation,
    read_boxes,
)
from arcf.eval.metrics import (
    PRECISION_THRESHOLDS,
    SUCCESS_THRESHOLDS,
    Convention,
    DatasetScore,
    SequenceScore,
    aggregate,
    auc,
    center_errors,
    overlaps,
    precision_curve,
    score_dataset,
    score_sequence,
    success_curve,
)
from arcf.eval.results import ResultsError, read_results, score_folder, write_results

__all__ = [
    "PRECISION_THRESHOLDS",
    "SUCCESS_THRESHOLDS",
    "Convention",
    "DatasetError",
    "DatasetScore",
    "ResultsError",
    "Sequence",
    "SequenceScore",
    "aggregate",
    "auc",
    "center_errors",
    "list_frames",
    "load_dataset",
    "load_dtb70",
    "load_sequence",
    "load_uav123_10fps",
    "load_uavdt",
    "overlaps",
    "precision_curve",
    "read_annotation",
    "read_boxes",
    "read_results",
    "score_dataset",
    "score_folder",
    "score_sequence",
    "success_curve",
    "write_results",
]

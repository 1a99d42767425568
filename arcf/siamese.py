"""Siamese trackers beside ARCF: OpenCV's NanoTrack v2 and VitTrack behind ``init`` /
``update -> TrackResult``.

A Siamese tracker matches a template of the target, cut at ``init`` and never updated, against
a search region around its last box with a network trained offline on large tracking datasets;
OpenCV runs the ONNX files (:mod:`arcf.models`). What each reports:

* ``box``: the network's, in the datasets' 1-based convention (OpenCV's boxes are 0-based
  integer ``(x, y, w, h)``);
* ``peak``: the network's score (``getTrackingScore``); ``psr`` and the aberrances are NaN:
  there is no response map to read;
* ``confidence``: the score, clipped to [0, 1];
* ``state``: the score against its median over the track's recent trusted frames, through the
  same state machine as ARCF's (:class:`arcf.state.TrackMonitor`). VitTrack's score falls when
  its target is hidden; NanoTrack's hardly moves (0.7-0.99 whatever it follows), so its state
  rarely leaves ``tracking``: that is what the network says about itself.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .errors import NotInitializedError
from .models import model_paths
from .presets import SiameseParams
from .region import Region, RegionFrame, whole_frame
from .state import TrackMonitor, TrackState
from .types import Box, TrackResult, validate_box, validate_frame


def opencv_tracker(network: str, models_dir: str | Path | None = None) -> Any:
    """A fresh OpenCV tracker of ``network`` on the checked files under ``models_dir``."""
    paths = [str(p) for p in model_paths(network, models_dir)]
    if network == "nanotrack":
        params = cv2.TrackerNano_Params()  # type: ignore[attr-defined]  # no stub
        params.backbone, params.neckhead = paths
        return cv2.TrackerNano_create(params)  # type: ignore[attr-defined]
    params = cv2.TrackerVit_Params()  # type: ignore[attr-defined]
    params.net = paths[0]
    return cv2.TrackerVit_create(params)  # type: ignore[attr-defined]


def to_opencv(box: Box, image_hw: tuple[int, int]) -> tuple[int, int, int, int]:
    """A 1-based ``(x, y, w, h)`` box as OpenCV's 0-based integer rectangle, inside the frame
    (the networks crop their template around it)."""
    rows, cols = image_hw
    x0 = min(max(round(box[0] - 1), 0), cols - 1)
    y0 = min(max(round(box[1] - 1), 0), rows - 1)
    w = max(1, min(round(box[2]), cols - x0))
    h = max(1, min(round(box[3]), rows - y0))
    return x0, y0, w, h


def as_bgr(frame: np.ndarray) -> np.ndarray:
    """The networks read 3-channel BGR frames: grey ones are repeated."""
    if frame.ndim == 2 or frame.shape[2] == 1:
        return cv2.cvtColor(frame.reshape(frame.shape[:2]), cv2.COLOR_GRAY2BGR)
    return frame


class SiameseTracker:
    """NanoTrack or VitTrack (:class:`~arcf.presets.SiameseParams`), the field's interface."""

    def __init__(self, params: SiameseParams, models_dir: str | Path | None = None, *,
                 colornames_path: str | Path | None = None) -> None:
        # colornames_path: the registry's common signature (arcf.registry); unused here
        self.params = params
        self._models_dir = models_dir
        # the files are checked now, so a missing network fails at creation, not mid-stream
        model_paths(params.network, models_dir)
        self._net: Any = None
        self._monitor = TrackMonitor(params.state)
        self._frame_index = 0
        self._image_hw: tuple[int, int] | None = None
        self._scale_ref = 1.0
        #: the last frame's score over its median on the recent trusted frames
        self.strength = math.nan

    @property
    def initialized(self) -> bool:
        return self._net is not None

    def init(self, frame: np.ndarray, box: Box | Any) -> TrackResult:
        """Start (or restart) on ``box``; a failed restart leaves the running track as it was."""
        validate_frame(frame)
        x, y, w, h = validate_box(box, frame.shape[:2])
        net = opencv_tracker(self.params.network, self._models_dir)
        net.init(as_bgr(frame), to_opencv((x, y, w, h), frame.shape[:2]))
        self._net, self._image_hw, self._frame_index = net, frame.shape[:2], 0
        self._scale_ref = math.sqrt(w * h)
        self._monitor.reset()
        return TrackResult(box=(x, y, w, h), peak=1.0, psr=math.nan, aberrance=math.nan,
                           aberrance_release=math.nan, scale=1.0, frame_index=0)

    def read_region(self) -> Region | None:
        """None: OpenCV's network cuts its own search window from the whole frame."""
        return None

    def update(self, frame: np.ndarray | RegionFrame) -> TrackResult:
        if self._net is None:
            raise NotInitializedError("call init(frame, box) before update(frame)")
        frame = whole_frame(frame)
        validate_frame(frame)
        if frame.shape[:2] != self._image_hw:
            from .errors import InvalidFrameError

            raise InvalidFrameError(
                f"frame size changed from {self._image_hw} to {frame.shape[:2]}; call init() "
                "again for a new stream")
        located, rect = self._net.update(as_bgr(frame))
        score = float(self._net.getTrackingScore())
        if not math.isfinite(score):
            score = 0.0
        self._frame_index += 1
        if not located or score < self.params.score_threshold:
            score = min(score, self.params.score_threshold)
        verdict = self._monitor.observe(score, 1.0, 0.0)
        self.strength = verdict.strength
        x0, y0, w, h = (float(v) for v in rect)
        w, h = max(w, 1.0), max(h, 1.0)
        return TrackResult(
            box=(x0 + 1, y0 + 1, w, h), peak=score, psr=math.nan, aberrance=math.nan,
            aberrance_release=math.nan, scale=math.sqrt(w * h) / self._scale_ref,
            frame_index=self._frame_index, confidence=min(max(score, 0.0), 1.0),
            state=verdict.state if located else TrackState.LOST)

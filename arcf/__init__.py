"""arcf: the ARCF visual trackers (Huang, Fu, Li, Lin and Lu, "Learning Aberrance Repressed
Correlation Filters for Real-Time UAV Tracking", ICCV 2019) in NumPy/OpenCV.

>>> import arcf
>>> tracker = arcf.create_tracker("arcf-hc")           # or "arcf-h", "bacf"; overrides by keyword
>>> tracker.init(frame, (x, y, w, h))                  # doctest: +SKIP
>>> result = tracker.update(next_frame)                # doctest: +SKIP
>>> result.box, result.peak, result.psr, result.aberrance  # doctest: +SKIP
>>> for step in arcf.track_frames(tracker, frames, box):  # doctest: +SKIP
...     print(step.result.box, step.seconds)             # the one loop, timed per frame
"""

from .errors import (
    ARCFError,
    ColorNamesNotFoundError,
    InvalidBoxError,
    InvalidFrameError,
    NotInitializedError,
    UnknownPresetError,
)
from .presets import (
    ARCF_H,
    ARCF_HC,
    BACF,
    PRESETS,
    RELEASE_COMPATIBLE,
    ScaleFilterParams,
    TrackerParams,
    make_params,
)
from .run import SequenceRun, Step, run_sequence, track_frames
from .tracker import ARCFTracker, TrackResult, create_tracker
from .warmup import warm_up

__version__ = "0.1.0"

__all__ = [
    "ARCF_H",
    "ARCF_HC",
    "BACF",
    "PRESETS",
    "RELEASE_COMPATIBLE",
    "ARCFError",
    "ARCFTracker",
    "ColorNamesNotFoundError",
    "InvalidBoxError",
    "InvalidFrameError",
    "NotInitializedError",
    "ScaleFilterParams",
    "SequenceRun",
    "Step",
    "TrackResult",
    "TrackerParams",
    "UnknownPresetError",
    "create_tracker",
    "make_params",
    "run_sequence",
    "track_frames",
    "warm_up",
]

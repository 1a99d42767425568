"""arcf: the ARCF visual trackers (Huang, Fu, Li, Lin and Lu, "Learning Aberrance Repressed
Correlation Filters for Real-Time UAV Tracking", ICCV 2019) in NumPy/OpenCV.

>>> import arcf
>>> tracker = arcf.create_tracker("arcf-hc")           # or "arcf-h", "bacf"; overrides by keyword
>>> tracker.init(frame, (x, y, w, h))                  # doctest: +SKIP
>>> result = tracker.update(next_frame)                # doctest: +SKIP
>>> result.box, result.peak, result.psr, result.aberrance  # doctest: +SKIP
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
    "TrackResult",
    "TrackerParams",
    "UnknownPresetError",
    "create_tracker",
    "make_params",
    "warm_up",
]

"""arcf: the ARCF visual trackers (Huang, Fu, Li, Lin and Lu, "Learning Aberrance Repressed
Correlation Filters for Real-Time UAV Tracking", ICCV 2019) in NumPy/OpenCV.

>>> import arcf
>>> tracker = arcf.create_tracker("arcf-hc")           # or "arcf-h", "bacf"; overrides by keyword
>>> # "nanotrack", "vittrack": Siamese networks (OpenCV); "arcf-nano": NanoTrack checked by ARCF
>>> tracker.init(frame, (x, y, w, h))                  # doctest: +SKIP
>>> result = tracker.update(next_frame)                # doctest: +SKIP
>>> result.box, result.peak, result.psr, result.aberrance  # doctest: +SKIP
>>> for step in arcf.track_frames(tracker, frames, box):  # doctest: +SKIP
...     print(step.result.box, step.seconds)             # the one loop, timed per frame
"""

# The names below load on first use (PEP 562), so that ``import arcf.schemas`` or a client of
# ``arcf.service`` does not pay for the tracker's NumPy/OpenCV/Numba stack.
from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .errors import (
        ARCFError,
        ColorNamesNotFoundError,
        InvalidBoxError,
        InvalidFrameError,
        NotInitializedError,
        UnknownPresetError,
    )
    from .hybrid import HybridTracker
    from .models import ModelNotFoundError
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
    from .registry import ALL_PRESETS, create_tracker
    from .run import SequenceRun, Step, run_sequence, track_frames
    from .siamese import SiameseTracker
    from .tracker import ARCFTracker
    from .types import Tracker, TrackResult
    from .warmup import warm_up

try:  # the one place the version is written is pyproject.toml
    __version__ = version("arcf")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

#: public name -> the module that defines it
_HOME = {
    **dict.fromkeys(("ARCFError", "ColorNamesNotFoundError", "InvalidBoxError",
                     "InvalidFrameError",
    "ModelNotFoundError", "NotInitializedError", "UnknownPresetError"), "errors"),
    "ALL_PRESETS": "registry",
    **dict.fromkeys(("ARCF_H", "ARCF_HC", "BACF", "PRESETS", "RELEASE_COMPATIBLE",
                     "ScaleFilterParams", "TrackerParams", "make_params"), "presets"),
    **dict.fromkeys(("SequenceRun", "Step", "run_sequence", "track_frames"), "run"),
    **dict.fromkeys(("TrackResult", "Tracker"), "types"),
    "ARCFTracker": "tracker",
    "create_tracker": "registry",
    "SiameseTracker": "siamese",
    "HybridTracker": "hybrid",
    "ModelNotFoundError": "models",
    "warm_up": "warmup",
}


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'arcf' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{home}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_HOME])


__all__ = [
    "ALL_PRESETS",
    "ARCF_H",
    "ARCF_HC",
    "BACF",
    "PRESETS",
    "RELEASE_COMPATIBLE",
    "ARCFError",
    "ARCFTracker",
    "ColorNamesNotFoundError",
    "HybridTracker",
    "InvalidBoxError",
    "InvalidFrameError",
    "ModelNotFoundError",
    "NotInitializedError",
    "ScaleFilterParams",
    "SequenceRun",
    "SiameseTracker",
    "Step",
    "TrackResult",
    "Tracker",
    "TrackerParams",
    "UnknownPresetError",
    "create_tracker",
    "make_params",
    "run_sequence",
    "track_frames",
    "warm_up",
]

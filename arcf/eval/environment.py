"""The machine and the software a figure was measured with.

Every benchmark prints this beside its figures: speed ratios differ between CPUs, and accuracy
moves with the libraries (NanoTrack's boxes moved by +0.07 AUC from OpenCV 5.0 to 5.1, whose
DNN module runs the network).
"""

from __future__ import annotations

import contextlib
import os
import platform
from importlib import metadata
from pathlib import Path


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what the platform says."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine() or "unknown"


def versions() -> dict[str, str]:
    """Python's version and those of the libraries that decide the figures: NumPy and OpenCV
    (accuracy and speed), SciPy and Numba (speed)."""
    out = {"Python": platform.python_version()}
    for name, dist in (("NumPy", "numpy"), ("OpenCV", "opencv-python-headless"),
                       ("SciPy", "scipy"), ("Numba", "numba")):
        try:
            out[name] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    if "OpenCV" not in out:  # another OpenCV wheel (opencv-python, a local build)
        with contextlib.suppress(ImportError):
            import cv2

            out["OpenCV"] = cv2.__version__
    return out


def describe() -> str:
    """One line: CPU, ``nproc`` and the versions, e.g. ``Intel(R) Xeon(R) Processor, nproc 2,
    Python 3.11.7, NumPy 2.4.6, OpenCV 5.1.0.95, SciPy 1.17.1, Numba 0.68.1``."""
    parts = [cpu_model(), f"nproc {os.cpu_count()}"]
    parts += [f"{k} {v}" for k, v in versions().items()]
    return ", ".join(parts)

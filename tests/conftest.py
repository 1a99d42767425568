"""Fixtures shared by the library's and the service's tests."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import pytest

from arcf.data import data_root

#: frame k -> (the frame, the target's box, None while hidden)
Scene = Callable[[int], tuple[np.ndarray, tuple[int, int, int, int] | None]]


@pytest.fixture(scope="session")
def hidden_target_scene() -> Scene:
    """A textured 36-px target crossing a real background (boat1's first frame at 480x270),
    hidden for frames 30-39, then back far outside the search window it left (a camera pan,
    an occlusion while it moved): what re-acquisition is for."""
    first = data_root() / "uav123_10fps" / "data_seq" / "boat1" / "000001.jpg"
    if not first.is_file():
        pytest.skip("needs ../shared/data")
    background = cv2.resize(cv2.imread(str(first)), (480, 270), interpolation=cv2.INTER_AREA)
    rng = np.random.default_rng(3)
    target = cv2.resize(rng.integers(0, 256, (6, 6, 3), dtype=np.uint8), (36, 36),
                        interpolation=cv2.INTER_NEAREST)

    def scene(k: int) -> tuple[np.ndarray, tuple[int, int, int, int] | None]:
        frame = background.copy()
        if 30 <= k < 40:
            return frame, None
        x, y = (60 + 2 * k, 80) if k < 30 else (330 + k % 3, 170)
        frame[y:y + 36, x:x + 36] = target
        return frame, (x + 1, y + 1, 36, 36)

    return scene


@pytest.fixture(scope="session")
def wakeboard7():  # type: ignore[no-untyped-def]
    """UAV123@10fps wakeboard7 (1280x720 JPEG frames, a small moving target), the service
    and adapter tests' real stream; skipped where ../shared/data is absent."""
    from arcf.eval import load_dataset

    try:
        (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    except (FileNotFoundError, KeyError):
        pytest.skip("needs ../shared/data")
    return seq

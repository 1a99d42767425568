"""Fixtures shared by the library's and the service's tests."""

from __future__ import annotations

import ast
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
import pytest

from arcf.data import data_root


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    """The tracker's compiled kernels in Numba's cache before the first test.

    Why: a fresh clone has none, and compiling them takes about a minute of a core (several
    on a loaded machine). Every worker of the first service a test starts would compile them
    at once, against the service's start-up allowance (``worker_start_s``); compiled here
    once, each worker loads them in a second or two."""
    import arcf

    arcf.warm_up()


def _loaded_after(code: str, *packages: str) -> list[str]:
    """The modules among ``packages`` (each, or any module under it) that a fresh interpreter
    has loaded once it ran ``code``: the way to see what an import drags in, since this
    process has long loaded everything."""
    probe = (f"import sys\n{code}\nnames = {packages!r}\n"
             "print(sorted(m for m in sys.modules if m in names "
             "or m.startswith(tuple(n + '.' for n in names))))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120, check=True)
    loaded: list[str] = ast.literal_eval(out.stdout.strip())
    return loaded


@pytest.fixture
def loaded_after() -> Callable[..., list[str]]:
    """``loaded_after(code, *packages)``: which of ``packages`` (or modules under them) a
    fresh interpreter has loaded after running ``code``; the layer tests' one probe."""
    return _loaded_after


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


@dataclass(frozen=True)
class ReacquireScenario:
    """:func:`hidden_target_scene` as a clip for the surfaces that take overrides (the CLI,
    the service, its adapters): frame ``k`` as an image or as the JPEG bytes a station
    sends, and the check that a session re-acquired the target where it came back."""

    scene: Scene
    #: frames 0..length-1: the target hidden for 30-39, back far away from 40 on
    length: int = 70
    back: int = 40

    @property
    def init_box(self) -> tuple[int, int, int, int]:
        box = self.scene(0)[1]
        assert box is not None
        return box

    def image(self, k: int) -> np.ndarray:
        return self.scene(k)[0]

    def target(self, k: int) -> tuple[int, int, int, int] | None:
        return self.scene(k)[1]

    @cached_property
    def jpegs(self) -> tuple[bytes, ...]:
        """Every frame JPEG-encoded (quality 90, the SDK's default)."""
        return tuple(cv2.imencode(".jpg", self.image(k), [cv2.IMWRITE_JPEG_QUALITY, 90])[1]
                     .tobytes() for k in range(self.length))

    def on_target(self, k: int, box: Sequence[float]) -> bool:
        """``box`` (1-based x, y, w, h) overlaps the target of frame ``k`` by IoU > 0.5."""
        target = self.target(k)
        return target is not None and iou(box, target) > 0.5

    def found_back(self, boxes: Mapping[int, Sequence[float]]) -> list[int]:
        """The frames (after the target came back) whose box is on the target's new place."""
        return [k for k, box in sorted(boxes.items()) if k >= self.back
                and self.on_target(k, box)]

    def reacquisitions(self, results: Iterable[tuple[int, Sequence[float], bool]]
                       ) -> list[int]:
        """The frames where a result, ``(frame k, box, reacquired)``, says it re-acquired the
        target and its box is on the target's new place (whichever frame that happens on)."""
        return [k for k, box, reacquired in results
                if reacquired and k >= self.back and self.on_target(k, box)]

    def replay(self, publish: Callable[[int, bytes], object], answered: Callable[[int], bool],
               *, start: int = 0, timeout: float = 30.0) -> None:
        """Send frames ``start``.. in lock-step: ``publish(k, jpeg)``, then wait (at most
        ``timeout`` seconds a frame) until ``answered(k)``, so that every frame is tracked
        whatever the machine's speed."""
        for k in range(start, self.length):
            publish(k, self.jpegs[k])
            deadline = time.monotonic() + timeout
            while not answered(k):
                if time.monotonic() > deadline:
                    raise AssertionError(f"frame {k} of the scenario got no result within "
                                         f"{timeout:g} s")
                time.sleep(0.005)


def iou(a: Sequence[float], b: Sequence[float]) -> float:
    """Intersection over union of two x, y, w, h boxes."""
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = a[2] * a[3] + b[2] * b[3] - inter
    return inter / union if union > 0 else 0.0


@pytest.fixture(scope="session")
def reacquire_scenario(hidden_target_scene: Scene) -> ReacquireScenario:
    """The hidden target scene (found again by every preset with ``state.reacquire`` on, never
    without it: tests/arcf/test_reacquire.py) as a clip with its re-acquisition check."""
    return ReacquireScenario(hidden_target_scene)


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

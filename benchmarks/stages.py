"""Where a tracker's frame goes, stage by stage, next to each stage's floor.

Used by ``benchmarks/speed.py --stages``: the tracker's stage functions are wrapped with timers
in the benchmark's worker process (never in the library), each call's *exclusive* time is
charged to its stage (a stage nested in another, e.g. the FFTs inside ADMM, is not counted
twice), and the sizes each stage handles are recorded so that its floor can be computed:

- **sampling**: reading each source pixel of every window once (window bytes / the machine's
  memory copy bandwidth, measured in the same process);
- **features**: reading each patch once and writing its feature maps once (same bandwidth);
- **FFT**: the same transforms (kind, grid, number of maps) as one large batched call each, on
  preallocated arrays: what ``scipy.fft`` can do at best on these shapes;
- **ADMM** (FFTs excluded): per iteration, one pass over the six spectra the g- and h-steps
  read or write (x̂, x̂ỹ, ζ̂, ĥ, ĝ, μĝ + ζ̂), at the same bandwidth;
- detection (correlation, inverse transform of the maps, Newton, PSR), aberrance and the scale
  filter's own arithmetic have no floor given here (—).
"""

from __future__ import annotations

import time
from collections import Counter, defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np

STAGES = ("sampling", "features", "FFT", "ADMM", "detection", "aberrance", "scale filter",
          "other")


class StageTimer:
    """Wraps functions with exclusive-time accounting; ``seconds[stage]``, ``bytes[stage]``."""

    def __init__(self) -> None:
        self.seconds: defaultdict[str, float] = defaultdict(float)
        self.bytes: Counter[str] = Counter()
        self.fft_maps: Counter[tuple[str, tuple[int, ...], str]] = Counter()
        self.admm_bytes = 0
        self._stack: list[float] = []  # time spent in nested wrapped calls, per open call
        self._patched: list[tuple[Any, str, Any]] = []

    def wrap(self, owner: Any, name: str, stage: str,
             account: Callable[[tuple[Any, ...], dict[str, Any], Any], None] | None = None
             ) -> None:
        original = getattr(owner, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            self._stack.append(0.0)
            t0 = time.perf_counter()
            try:
                result = original(*args, **kwargs)
            finally:
                elapsed = time.perf_counter() - t0
                nested = self._stack.pop()
                self.seconds[stage] += elapsed - nested
                if self._stack:
                    self._stack[-1] += elapsed
            if account is not None:
                account(args, kwargs, result)
            return result

        self._patched.append((owner, name, original))
        setattr(owner, name, timed)

    def restore(self) -> None:
        for owner, name, original in reversed(self._patched):
            setattr(owner, name, original)
        self._patched.clear()


def instrument() -> StageTimer:
    """Wrap the library's stage functions (call before creating the tracker)."""
    import scipy.fft as sfft

    from arcf import scale, tracker
    from arcf.features import extract

    timer = StageTimer()

    def windows(args: tuple[Any, ...], kwargs: dict[str, Any], result: Any) -> None:
        image, _, sizes = args[:3]
        channels = image.shape[2] if image.ndim == 3 else 1
        timer.bytes["sampling"] += sum(h * w for h, w in sizes) * channels + result.nbytes

    def features(args: tuple[Any, ...], kwargs: dict[str, Any], result: Any) -> None:
        timer.bytes["features"] += args[0].nbytes + result.nbytes

    def fft(kind: str) -> Callable[[tuple[Any, ...], dict[str, Any], Any], None]:
        def account(args: tuple[Any, ...], kwargs: dict[str, Any], result: Any) -> None:
            x = np.asarray(args[0])
            precision = "single" if x.dtype in (np.float32, np.complex64) else "double"
            if kind in ("fft", "ifft", "rfft", "irfft"):  # 1-D passes along one axis
                n_in = x.shape[kwargs.get("axis", -1)]
                n = int(kwargs["n"]) if kind == "irfft" else n_in
                timer.fft_maps[(kind, (n,), precision)] += x.size // n_in
                return
            size = kwargs.get("s")
            grid = tuple(x.shape[-2:]) if size is None else tuple(int(v) for v in size)
            if kind == "irfftn" and tuple(kwargs.get("axes", ())) == (-1, -2):
                grid = grid[::-1]  # s is given in the axes' order, (W, H)
            timer.fft_maps[(kind, grid, precision)] += x.size // (x.shape[-1] * x.shape[-2])
        return account

    def admm_account(args: tuple[Any, ...], kwargs: dict[str, Any], result: Any) -> None:
        timer.admm_bytes += 6 * args[0].nbytes * kwargs["iterations"]

    for owner in (tracker, scale):
        timer.wrap(owner, "release_windows", "sampling", windows)
        timer.wrap(owner, "pyramid_windows", "sampling", windows)
    # windows stay BGR: ARCF-HC's pixel features convert their copy inside the extractor
    timer.wrap(extract.FeatureExtractor, "__call__", "features",
               lambda a, k, r: features(a[1:], k, r))
    timer.wrap(scale, "fhog", "features", features)
    for kind in ("fft", "ifft", "rfft", "irfft", "fft2", "ifft2", "rfft2", "irfft2", "irfftn"):
        timer.wrap(sfft, kind, "FFT", fft(kind))
    timer.wrap(tracker, "solve_filter", "ADMM", admm_account)
    for name in ("correlate", "spatial_response", "newton_peak", "peak_to_sidelobe"):
        timer.wrap(tracker, name, "detection")
    for name in ("map_difference", "shift_to", "release_target", "paper_target", "peak_index"):
        timer.wrap(tracker, name, "aberrance")
    timer.wrap(scale.DSSTScaleFilter, "estimate", "scale filter")
    timer.wrap(scale.DSSTScaleFilter, "update", "scale filter")
    return timer


def copy_bandwidth() -> float:
    """Bytes per second of a 32 MB ``np.copyto`` (read + write counted once), best of 5."""
    src = np.ones(32 << 20, np.uint8)
    dst = np.empty_like(src)
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        np.copyto(dst, src)
        best = min(best, time.perf_counter() - t0)
    return src.nbytes / best


def fft_floor(maps: Counter[tuple[str, tuple[int, ...], str]]) -> float:
    """Seconds for the recorded transforms done as one batched call per (kind, grid, precision):
    a 2-D grid counts maps, a 1-D one lines (the pruned passes of the h-step, the scale filter's
    transforms)."""
    total = 0.0
    batch = 64
    for (kind, grid, precision), count in maps.items():
        call = _batched_transform(kind, grid, precision == "single", batch)
        call()
        best = float("inf")
        for _ in range(5):
            t0 = time.perf_counter()
            call()
            best = min(best, time.perf_counter() - t0)
        total += best / batch * count
    return total


def _batched_transform(kind: str, grid: tuple[int, ...], single: bool,
                       batch: int) -> Callable[[], Any]:
    import scipy.fft as sfft

    real_t, complex_t = (np.float32, np.complex64) if single else (np.float64, np.complex128)
    if len(grid) == 1:
        (n,) = grid
        if kind == "rfft":
            line = np.ones((batch, n), real_t)
            return lambda: sfft.rfft(line, axis=-1)
        if kind == "irfft":
            half = np.ones((batch, n // 2 + 1), complex_t)
            return lambda: sfft.irfft(half, n=n, axis=-1)
        lines = np.ones((batch, n), complex_t)
        one_d = sfft.fft if kind == "fft" else sfft.ifft
        return lambda: one_d(lines, axis=-1)
    if kind == "rfft2":
        real = np.ones((batch, *grid), real_t)
        return lambda: sfft.rfft2(real)
    if kind in ("irfft2", "irfftn"):
        half2 = np.ones((batch, grid[0], grid[1] // 2 + 1), complex_t)
        return lambda: sfft.irfft2(half2, s=grid)
    full = np.ones((batch, *grid), complex_t)
    two_d = sfft.fft2 if kind == "fft2" else sfft.ifft2
    return lambda: two_d(full)


def report(timer: StageTimer, total_s: float) -> dict[str, Any]:
    """Per-stage seconds (``other`` = the rest of the frame) and floors, JSON-ready."""
    bandwidth = copy_bandwidth()
    seconds: dict[str, float] = defaultdict(float, timer.seconds)
    seconds["other"] = max(total_s - sum(timer.seconds.values()), 0.0)
    floors = {
        "sampling": timer.bytes["sampling"] / bandwidth,
        "features": timer.bytes["features"] / bandwidth,
        "FFT": fft_floor(timer.fft_maps),
        "ADMM": timer.admm_bytes / bandwidth,
    }
    return {"seconds": {s: seconds[s] for s in STAGES}, "floors": floors,
            "bandwidth": bandwidth}

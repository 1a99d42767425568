"""``resize_area`` is OpenCV's INTER_AREA shrink bit for bit (the release samples with it)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from arcf.features.patches import resize_auto
from arcf.features.resize import resize_area


def _opencv(image: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    out = cv2.resize(image, (out_hw[1], out_hw[0]), interpolation=cv2.INTER_AREA)
    return out[..., None] if out.ndim < image.ndim else out


@pytest.mark.parametrize("channels", [None, 1, 3])
def test_random_shrinks_equal_opencv(channels: int | None) -> None:
    rng = np.random.default_rng(7 if channels is None else channels)
    for _ in range(150):
        h, w = (int(v) for v in rng.integers(2, 260, 2))
        oh = max(1, int(h / rng.uniform(1.0, 9.0)))
        ow = max(1, int(w / rng.uniform(1.0, 9.0)))
        shape = (h, w) if channels is None else (h, w, channels)
        image = rng.integers(0, 256, shape, dtype=np.uint8)
        np.testing.assert_array_equal(resize_area(image, (oh, ow)), _opencv(image, (oh, ow)))


def test_saturated_and_smooth_images_equal_opencv() -> None:
    """Sums near 0 and 255 (saturation, rounding half to even) and smooth natural gradients."""
    rng = np.random.default_rng(3)
    smooth = cv2.GaussianBlur(rng.integers(0, 256, (777, 1111, 3), dtype=np.uint8), (0, 0), 4)
    for image in (
        np.full((301, 257, 3), 255, np.uint8),
        np.zeros((301, 257, 3), np.uint8),
        rng.choice(np.array([0, 255], np.uint8), (301, 257, 3)),
        smooth,
    ):
        for out_hw in ((200, 200), (57, 33), (1, 1), (150, 256)):
            np.testing.assert_array_equal(resize_area(image, out_hw), _opencv(image, out_hw))


def test_views_integer_ratios_and_enlargements_equal_opencv() -> None:
    """A window cut from a frame (a strided view), OpenCV's integer fast path, and mixed
    shrink / enlarge ratios all give OpenCV's result."""
    rng = np.random.default_rng(5)
    frame = rng.integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    window = frame[101:1012, 250:1161]
    np.testing.assert_array_equal(resize_area(window, (200, 200)), _opencv(window, (200, 200)))
    for out_hw in ((180, 320), (360, 640), (720, 2000), (1000, 100)):
        np.testing.assert_array_equal(resize_area(frame, out_hw), _opencv(frame, out_hw))


def test_resize_auto_keeps_the_release_rule() -> None:
    """Area when the new width does not exceed the old height, linear otherwise
    (docs/release.md, detail 8)."""
    rng = np.random.default_rng(11)
    patch = rng.integers(0, 256, (22, 48, 3), dtype=np.uint8)  # DSST-like: wide, short
    linear = cv2.resize(patch, (32, 15), interpolation=cv2.INTER_LINEAR)
    np.testing.assert_array_equal(resize_auto(patch, (15, 32)), linear)
    tall = rng.integers(0, 256, (48, 22, 3), dtype=np.uint8)
    np.testing.assert_array_equal(resize_auto(tall, (32, 15)), _opencv(tall, (32, 15)))


def test_kernels_compile_in_memory_when_no_cache_can_be_written(monkeypatch) -> None:
    """Numba raises at definition time when it cannot write a cache (a read-only container);
    the kernels then compile without one instead of breaking the library's import."""
    import numba

    from arcf import _jit

    real_njit = numba.njit

    def njit(*args, cache=False, **kwargs):
        if cache:
            raise RuntimeError("cannot cache function 'f': no locator available for file 'x.py'")
        return real_njit(*args, **kwargs)

    monkeypatch.setattr(_jit.numba, "njit", njit)

    def twice(a):
        return 2 * a

    compiled = _jit.kernel(twice)
    assert compiled(21) == 42
    assert compiled.signatures  # compiled by Numba, not the Python function returned as is


def test_resample_area_is_opencv_area_on_whole_pixel_windows() -> None:
    """With a whole-pixel window, the fractional resampler is INTER_AREA of the crop."""
    from arcf.features.resize import resample_area

    rng = np.random.default_rng(13)
    image = rng.integers(0, 256, (300, 280, 3), dtype=np.uint8)
    for origin, extent, out_hw in (((10, 20), (250, 230), (200, 200)),
                                   ((0, 0), (300, 280), (57, 33))):
        crop = image[origin[0]: origin[0] + extent[0], origin[1]: origin[1] + extent[1]]
        np.testing.assert_array_equal(
            resample_area(image, origin, extent, out_hw), _opencv(crop, out_hw))


def test_resample_area_weights_fractional_borders_and_replicates_outside() -> None:
    """A window starting half a pixel into a step edge sees half of the edge pixel; parts of
    a window outside the image read the edge."""
    from arcf.features.resize import resample_area

    image = np.zeros((4, 8, 1), np.uint8)
    image[:, 4:] = 200
    # columns [3.5, 5.5) -> one output pixel: 0.5 * 0 + 1.5 * 200 over 2 px = 150
    out = resample_area(image, (0.0, 3.5), (4.0, 2.0), (1, 1))
    assert out[0, 0, 0] == 150
    outside = resample_area(image, (-10.0, 6.0), (4.0, 12.0), (2, 2))  # rows < 0, cols > 7
    assert (outside == 200).all()


def test_pyramid_windows_small_windows_are_the_release_sampler() -> None:
    """Windows less than twice the output are cut and resized exactly as bacf_patch does."""
    from arcf.features.patches import bacf_patch, pyramid_windows

    rng = np.random.default_rng(17)
    frame = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    sizes = [(150, 150), (199, 199), (120, 180)]
    out = pyramid_windows(frame, (100.6, 150.2), sizes, (100, 100))
    for got, size in zip(out, sizes, strict=True):
        np.testing.assert_array_equal(got, bacf_patch(frame, (100.6, 150.2), size, (100, 100)))


def test_pyramid_windows_approximate_the_area_resize_of_large_windows() -> None:
    """Large windows (ARCF-H's five scales around a large target, leaving the frame) come out
    within a few grey levels of the exact area resize, at the same place and scale."""
    from arcf.features.patches import bacf_patch, pyramid_windows

    rng = np.random.default_rng(19)
    frame = cv2.GaussianBlur(rng.integers(0, 256, (720, 1280, 3), dtype=np.uint8), (0, 0), 3)
    frame[300:420, 500:700] = 255  # a bright target: an error in placement or scale shows
    sides = [round(1111 * 1.01**k) for k in range(-2, 3)]
    pos = (360.0, 600.0)
    fast = pyramid_windows(frame, pos, [(s, s) for s in sides], (200, 200)).astype(int)
    exact = np.stack([bacf_patch(frame, pos, (s, s), (200, 200)) for s in sides]).astype(int)
    assert fast.shape == exact.shape == (5, 200, 200, 3)
    error = np.abs(fast - exact)
    assert error.mean() < 1.0 and np.percentile(error, 99) <= 4
    # the target lands at the same place with the same size at every scale (a half-pixel
    # slip of the window, or a scale off by one pixel of 1111, would move these)
    for f, e in zip(fast, exact, strict=True):
        mf, me = f[..., 0] > 180, e[..., 0] > 180
        assert abs(int(mf.sum()) - int(me.sum())) <= 0.01 * me.sum()
        for axis in (0, 1):
            cf = np.nonzero(mf)[axis].mean()
            ce = np.nonzero(me)[axis].mean()
            assert abs(cf - ce) < 0.05


def test_release_windows_are_bacf_patch_window_by_window() -> None:
    """Nested windows sharing one cut and one transposition equal the release's sampler one by
    one, whichever of mexResize's linear / area rules each window takes, also off the frame."""
    from arcf.features.patches import bacf_patch, release_windows

    rng = np.random.default_rng(23)
    frame = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    sizes = [(max(int(40 * 1.03**k), 2), max(int(90 * 1.03**k), 2)) for k in range(-16, 17)]
    for pos, out_hw in (((120.4, 160.9), (16, 32)), ((5.0, 310.0), (16, 32)),
                        ((120.0, 160.0), (30, 30))):
        got = release_windows(frame, pos, sizes, out_hw)
        for g, size in zip(got, sizes, strict=True):
            np.testing.assert_array_equal(g, bacf_patch(frame, pos, size, out_hw))


@pytest.mark.parametrize("channels", [1, 3])
def test_windows_leaving_the_image_read_its_edge_as_a_replicated_crop(channels: int) -> None:
    """Windows partly or wholly outside the image (the trackers' windows around a large
    target in a 720-px frame) equal OpenCV's area resize of the border-replicated crop, bit for
    bit, although no replicated copy is made (the area tables point at the edge pixel)."""
    from arcf.features.patches import crop_replicate
    from arcf.features.resize import resize_area_windows

    rng = np.random.default_rng(29 + channels)
    for _ in range(60):
        ih, iw = (int(v) for v in rng.integers(8, 120, 2))
        image = rng.integers(0, 256, (ih, iw, channels), dtype=np.uint8)
        out_hw = (int(rng.integers(4, 40)), int(rng.integers(4, 40)))
        windows = []
        for _ in range(int(rng.integers(1, 6))):
            h, w = (int(v) for v in rng.integers(2, 200, 2))
            top, left = rng.integers(-h - 20, ih + 20), rng.integers(-w - 20, iw + 20)
            windows.append((int(top), int(left), h, w))
        got = resize_area_windows(image, windows, out_hw)
        for g, (top, left, h, w) in zip(got, windows, strict=True):
            np.testing.assert_array_equal(g, _opencv(crop_replicate(image, top, left, h, w),
                                                     out_hw))


def test_halving_a_window_that_leaves_the_image_is_opencv_on_its_replicated_crop() -> None:
    """The pyramid's first level, built from the image inside and thin strips of its edge
    pixels, is OpenCV's 2x area shrink of the border-replicated window, bit for bit: windows
    inside, straddling each edge at either parity, wholly outside, grey and colour."""
    from arcf.features.patches import crop_replicate, halve_replicated

    rng = np.random.default_rng(31)
    for _ in range(400):
        ih, iw = (int(v) for v in rng.integers(3, 60, 2))
        image = rng.integers(0, 256, (ih, iw, int(rng.choice([1, 3]))), dtype=np.uint8)
        h, w = (2 * int(v) for v in rng.integers(1, 60, 2))
        top, left = int(rng.integers(-80, ih + 10)), int(rng.integers(-80, iw + 10))
        np.testing.assert_array_equal(
            halve_replicated(image, top, left, h, w),
            _opencv(crop_replicate(image, top, left, h, w), (h // 2, w // 2)))
    frame = rng.integers(0, 256, (720, 1280, 3), dtype=np.uint8)  # boat1's 1112-px window
    np.testing.assert_array_equal(halve_replicated(frame, -190, 40, 1112, 1112),
                                  _opencv(crop_replicate(frame, -190, 40, 1112, 1112), (556, 556)))

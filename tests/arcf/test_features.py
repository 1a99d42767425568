"""Pixel features, feature stacking, patch sampling and the Fourier helpers.

fHOG itself is covered by ``test_fhog.py``; here: the grayscale and Color Names channels, the
FeatureExtractor's block layout, patch sampling (BACF's ``get_pixels``, used by both trackers)
with border replication and the release's resize rule, the Gaussian label, Newton's sub-cell
peak search and the (non-)Hermitian inverse FFT. Patches are RGB, as the tracker hands them over.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.fft as sfft

from arcf.data import default_colornames_path
from arcf.errors import ColorNamesNotFoundError
from arcf.features.extract import CHANNELS, FeatureExtractor
from arcf.features.fhog import fhog
from arcf.features.patches import bacf_patch, crop_replicate, resize_auto
from arcf.features.pixel import RGB2GRAY, ColorNames, cell_average, gray_features
from arcf.fourier import (
    gaussian_label,
    newton_peak,
    peak_to_sidelobe,
    signed_indices,
    spatial_response,
)
from arcf.presets import ARCF_H, ARCF_HC

# --------------------------------------------------------------------------- helpers


def cn_index(r: int, g: int, b: int) -> int:
    """The documented Color Names row of an RGB pixel."""
    return r // 8 + 32 * (g // 8) + 1024 * (b // 8)


@pytest.fixture()
def index_table(tmp_path: Path) -> Path:
    """A fake 32768x10 table whose row i encodes i, so a lookup reveals the row it used."""
    i = np.arange(32768, dtype=np.float32)
    table = np.stack([i, i % 32, (i // 32) % 32, i // 1024] + [np.full_like(i, 0.5)] * 6, axis=1)
    path = tmp_path / "cn_norm_32768x10.npy"
    np.save(path, table.astype(np.float32))
    return path


def real_table() -> Path:
    path = default_colornames_path()
    if not path.is_file():
        pytest.skip(f"Color Names table not found: {path} (set ARCF_DATA or ARCF_COLORNAMES)")
    return path


def coord_image(h: int, w: int) -> np.ndarray:
    """uint8 image whose channel 0 holds the row index and channel 1 the column index."""
    rows, cols = np.mgrid[0:h, 0:w]
    return np.stack([rows, cols], axis=-1).astype(np.uint8)


# --------------------------------------------------------------------------- gray / cells


def test_gray_feature_is_cell_mean_of_gray_over_255_minus_half() -> None:
    patch = np.zeros((8, 8), np.uint8)
    patch[:4, :4] = 255  # -> +0.5
    patch[:4, 4:] = 0  # -> -0.5
    patch[4:, :4] = np.array([[0, 255, 0, 255]] * 4)  # mean 127.5/255 - 0.5 = 0
    patch[4:, 4:] = 51  # 0.2 - 0.5 = -0.3
    out = gray_features(patch[None, ..., None], 4)
    assert out.shape == (1, 2, 2, 1) and out.dtype == np.float32
    np.testing.assert_allclose(out[0, ..., 0], [[0.5, -0.5], [0.0, -0.3]], atol=1e-6)


def test_gray_feature_arbitrary_values_and_cells() -> None:
    rng = np.random.default_rng(1)
    patch = rng.integers(0, 256, size=(2, 11, 14, 1), dtype=np.uint8)
    for cell in (1, 2, 3, 4):
        out = gray_features(patch, cell)
        hb, wb = 11 // cell, 14 // cell
        assert out.shape == (2, hb, wb, 1)
        g = patch[:, : hb * cell, : wb * cell, 0].astype(np.float64) / 255 - 0.5
        expected = g.reshape(2, hb, cell, wb, cell).mean(axis=(2, 4))
        np.testing.assert_allclose(out[..., 0], expected, atol=1e-6)


def rgb2gray_float(r: float, g: float, b: float) -> float:
    """MATLAB's ``rgb2gray`` of one pixel of ``single(im) / 255`` (no 8-bit rounding)."""
    return (0.298936021293775 * r + 0.587043074451121 * g + 0.114020904255103 * b) / 255


def test_gray_feature_of_a_colour_patch_uses_float_rgb2gray() -> None:
    """Patches are RGB; grey is rgb2gray of the float image in [0, 1], minus 0.5 (release)."""
    np.testing.assert_array_equal(
        RGB2GRAY, [0.298936021293775, 0.587043074451121, 0.114020904255103]
    )
    r, g, b = 90, 200, 10  # rgb2gray: 145.4534 / 255; rounding to 8-bit grey first gives 145
    patch = np.empty((1, 8, 12, 3), np.uint8)
    patch[...] = (r, g, b)  # RGB order
    out = gray_features(patch, 4)
    assert out.shape == (1, 2, 3, 1) and out.dtype == np.float32
    expected = rgb2gray_float(r, g, b) - 0.5
    np.testing.assert_allclose(out, expected, atol=1e-6)
    # not the 8-bit grey of OpenCV / MATLAB's uint8 rgb2gray (1.8e-3 away)
    assert abs(expected - (145 / 255 - 0.5)) > 1e-3
    assert not np.allclose(out, 145 / 255 - 0.5, atol=1e-4)
    # channel 0 is R: the same pixel in BGR order gives another value
    swapped = np.ascontiguousarray(patch[..., ::-1])
    np.testing.assert_allclose(gray_features(swapped, 4), rgb2gray_float(b, g, r) - 0.5, atol=1e-6)
    assert not np.allclose(gray_features(swapped, 4), out, atol=1e-3)


def test_gray_feature_of_a_colour_patch_arbitrary_values() -> None:
    """Per-pixel float rgb2gray, then the cell mean (float32 integral image: ~1e-7 here)."""
    rng = np.random.default_rng(12)
    patch = rng.integers(0, 256, size=(2, 13, 18, 3), dtype=np.uint8)
    for cell in (1, 3, 4):
        out = gray_features(patch, cell)
        hb, wb = 13 // cell, 18 // cell
        assert out.shape == (2, hb, wb, 1)
        p = patch[:, : hb * cell, : wb * cell].astype(np.float64)
        gray = rgb2gray_float(p[..., 0], p[..., 1], p[..., 2]) - 0.5
        expected = gray.reshape(2, hb, cell, wb, cell).mean(axis=(2, 4))
        np.testing.assert_allclose(out[..., 0], expected, atol=2e-6)


@pytest.mark.parametrize(
    ("shape", "cell", "grid"),
    [
        ((1, 10, 13, 2), 4, (2, 3)),
        ((3, 8, 8, 1), 4, (2, 2)),
        ((1, 7, 5, 3), 2, (3, 2)),
        ((1, 3, 3, 1), 4, (0, 0)),
        ((2, 5, 9, 4), 1, (5, 9)),
    ],
)
def test_cell_average_floors_the_grid(shape: tuple, cell: int, grid: tuple) -> None:
    maps = np.random.default_rng(0).random(shape).astype(np.float32)
    out = cell_average(maps, cell)
    assert out.shape == (shape[0], *grid, shape[3])
    for i in range(grid[0]):
        for j in range(grid[1]):
            block = maps[:, i * cell : (i + 1) * cell, j * cell : (j + 1) * cell]
            # float32 integral image (release): the rounding of running sums up to ~45 here
            # (float32 spacing 4e-6), divided by the cell area, not relative to the mean
            np.testing.assert_allclose(
                out[:, i, j], block.mean(axis=(1, 2)), rtol=1e-6, atol=1e-5
            )


def test_cell_average_is_the_release_float32_integral_image() -> None:
    """ECO's average_feature_region: float32 cumsum down the rows, then along the columns,
    four corner reads per cell, divided by the cell area; equal to that bit for bit, and to a
    block mean up to float32 rounding of the running sums (~3e-5 on a 200x200 patch)."""
    rng = np.random.default_rng(13)
    maps = (rng.random((2, 200, 203, 2)) - 0.5).astype(np.float32)
    cell = 4
    out = cell_average(maps, cell)
    assert out.shape == (2, 50, 50, 2) and out.dtype == np.float32
    integral = np.zeros((2, 201, 201, 2), np.float32)
    integral[:, 1:, 1:] = np.cumsum(
        np.cumsum(maps[:, :200, :200], axis=1, dtype=np.float32), axis=2, dtype=np.float32
    )
    c = integral[:, ::cell, ::cell]
    expected = (c[:, 1:, 1:] - c[:, 1:, :-1] - c[:, :-1, 1:] + c[:, :-1, :-1]) / np.float32(16)
    np.testing.assert_array_equal(out, expected)
    block = maps[:, :200, :200].astype(np.float64).reshape(2, 50, 4, 50, 4, 2).mean(axis=(2, 4))
    np.testing.assert_allclose(out, block, atol=1e-4)


# --------------------------------------------------------------------------- Color Names


def test_colornames_index_from_rgb_patches(index_table: Path) -> None:
    """Patches reach the features in RGB order (the tracker converts OpenCV's BGR frames)."""
    cn = ColorNames(index_table)
    r, g, b = 37, 100, 200
    patch = np.empty((1, 8, 8, 3), np.uint8)
    patch[...] = (r, g, b)  # RGB order: channel 0 is R
    out = cn(patch, 4)
    assert out.shape == (1, 2, 2, 10) and out.dtype == np.float32
    idx = cn_index(r, g, b)
    assert idx == 4 + 32 * 12 + 1024 * 25
    np.testing.assert_array_equal(out[..., 0], idx)
    np.testing.assert_array_equal(
        out[..., 1:4], np.broadcast_to([r // 8, g // 8, b // 8], (1, 2, 2, 3))
    )
    assert idx != cn_index(b, g, r)  # the RGB/BGR mix-up would be caught
    bgr = np.ascontiguousarray(patch[..., ::-1])
    np.testing.assert_array_equal(cn(bgr, 4)[..., 0], cn_index(b, g, r))


def test_colornames_every_bin_boundary(index_table: Path) -> None:
    cn = ColorNames(index_table)
    values = np.array([0, 7, 8, 15, 16, 127, 128, 247, 248, 255], np.uint8)
    r, g, b = np.meshgrid(values, values, values, indexing="ij")
    rgb = np.stack([r.ravel(), g.ravel(), b.ravel()], axis=-1)[None, None]  # (1, 1, n, 3)
    out = cn(rgb, 1)[0, 0, :, 0]
    expected = [
        cn_index(int(x), int(y), int(z))
        for x, y, z in zip(r.ravel(), g.ravel(), b.ravel(), strict=True)
    ]
    np.testing.assert_array_equal(out, expected)


def test_colornames_cell_mean_of_table_rows(index_table: Path) -> None:
    cn = ColorNames(index_table)
    patch = np.zeros((1, 4, 8, 3), np.uint8)
    patch[0, :, :4] = (255, 0, 0)  # red -> row 31
    patch[0, :, 4:6] = (0, 0, 255)  # blue -> row 31744
    patch[0, :, 6:] = (0, 255, 0)  # green -> row 992
    out = cn(patch, 4)
    assert out.shape == (1, 1, 2, 10)
    assert out[0, 0, 0, 0] == 31
    assert out[0, 0, 1, 0] == pytest.approx((31744 + 992) / 2)


def test_colornames_real_table_row() -> None:
    path = real_table()
    table = np.load(path)
    assert table.shape == (32768, 10)
    cn = ColorNames(path)
    rng = np.random.default_rng(5)
    for r, g, b in rng.integers(0, 256, size=(5, 3)):
        patch = np.empty((1, 4, 4, 3), np.uint8)
        patch[...] = (r, g, b)
        out = cn(patch, 4)[0, 0, 0]
        np.testing.assert_allclose(out, table[cn_index(int(r), int(g), int(b))], rtol=1e-6)


def test_colornames_missing_file(tmp_path: Path) -> None:
    missing = tmp_path / "absent.npy"
    with pytest.raises(ColorNamesNotFoundError, match=r"cn_norm_32768x10\.npy") as info:
        ColorNames(missing)
    assert "ARCF_COLORNAMES" in str(info.value) and str(missing) in str(info.value)


# --------------------------------------------------------------------------- FeatureExtractor


@pytest.mark.parametrize(
    ("kinds", "color", "channels"),
    [
        (ARCF_HC.features, True, 42),
        (ARCF_HC.features, False, 32),
        (ARCF_H.features, True, 31),
        (ARCF_H.features, False, 31),
        (("gray",), True, 1),
        (("cn",), True, 10),
    ],
)
def test_extractor_channel_counts_and_layout(
    kinds: tuple[str, ...], color: bool, channels: int, index_table: Path
) -> None:
    fx = FeatureExtractor(kinds, 4, str(index_table))
    assert fx.channels(color) == channels
    rng = np.random.default_rng(2)
    c = 3 if color else 1
    patches = rng.integers(0, 256, size=(3, 50, 42, c), dtype=np.uint8)
    out = fx(patches, color)
    assert out.shape == (3, channels, 50 // 4, 42 // 4)
    assert out.dtype == np.float32 and out.flags.c_contiguous


def test_extractor_block_order(index_table: Path) -> None:
    rng = np.random.default_rng(3)
    patches = rng.integers(0, 256, size=(2, 40, 36, 3), dtype=np.uint8)
    out = FeatureExtractor(("gray", "fhog", "cn"), 4, str(index_table))(patches, True)
    assert sum(CHANNELS.values()) == 42
    np.testing.assert_array_equal(out[:, 0], gray_features(patches, 4)[..., 0])
    # fHOG with the release's arithmetic by default
    release = fhog(patches, 4, arithmetic="release").transpose(0, 3, 1, 2)
    np.testing.assert_array_equal(out[:, 1:32], release)
    np.testing.assert_array_equal(
        out[:, 32:], ColorNames(index_table)(patches, 4).transpose(0, 3, 1, 2)
    )
    exact = FeatureExtractor(("gray", "fhog", "cn"), 4, str(index_table), fhog_arithmetic="exact")
    out_exact = exact(patches, True)
    np.testing.assert_array_equal(out_exact[:, 1:32], fhog(patches, 4).transpose(0, 3, 1, 2))
    np.testing.assert_array_equal(out_exact[:, [0, *range(32, 42)]], out[:, [0, *range(32, 42)]])
    assert not np.array_equal(out_exact[:, 1:32], release)
    # the cosine window applied in place: the same product as multiplying afterwards
    window = np.outer(np.hanning(10), np.hanning(9)).astype(np.float32)
    windowed = FeatureExtractor(("gray", "fhog", "cn"), 4, str(index_table))(patches, True, window)
    np.testing.assert_array_equal(windowed.view(np.uint32), (out * window).view(np.uint32))
    # ... and after ECO's normalisation when there is one (it scales before the window)
    eco = FeatureExtractor(("gray", "fhog", "cn"), 4, str(index_table), normalize=True)
    np.testing.assert_array_equal(eco(patches, True, window).view(np.uint32),
                                  (eco(patches, True) * window).view(np.uint32))
    # gray frames skip the Color Names block
    g = np.stack([cv2.cvtColor(p, cv2.COLOR_RGB2GRAY) for p in patches])[..., None]
    out_g = FeatureExtractor(("gray", "fhog", "cn"), 4, "/nonexistent.npy")(g, False)
    assert out_g.shape == (2, 32, 10, 9)
    np.testing.assert_array_equal(out_g[:, 0], gray_features(g, 4)[..., 0])


def test_extractor_loads_the_table_only_for_colour(tmp_path: Path) -> None:
    fx = FeatureExtractor(("gray", "fhog", "cn"), 4, str(tmp_path / "missing.npy"))
    fx.prepare(False)  # fine: gray frames do not need the table
    with pytest.raises(ColorNamesNotFoundError):
        fx.prepare(True)
    FeatureExtractor(("fhog",), 4, str(tmp_path / "missing.npy")).prepare(True)


# --------------------------------------------------------------------------- patches

SMALL = np.random.default_rng(4).integers(0, 256, size=(7, 9, 3), dtype=np.uint8)
PAD = 30


def padded_window(image: np.ndarray, top: int, left: int, h: int, w: int) -> np.ndarray:
    widths = ((PAD, PAD), (PAD, PAD)) + ((0, 0),) * (image.ndim - 2)
    big = np.pad(image, widths, mode="edge")
    return big[top + PAD : top + PAD + h, left + PAD : left + PAD + w]


WINDOWS = [
    (1, 2, 4, 5),  # inside
    (0, 0, 7, 9),  # the whole image
    (-3, 2, 6, 4),  # above
    (4, 2, 6, 4),  # below
    (2, -4, 3, 6),  # left
    (2, 6, 3, 6),  # right
    (-2, -3, 12, 15),  # larger than the image on every side
    (-10, -10, 4, 4),  # entirely outside, up-left
    (9, 12, 3, 2),  # entirely outside, down-right
    (-6, 3, 2, 2),  # entirely above
    (3, 11, 2, 3),  # entirely right
]


@pytest.mark.parametrize("window", WINDOWS)
@pytest.mark.parametrize("channels", [3, 1, 0])
def test_crop_replicate_matches_edge_padding(
    window: tuple[int, int, int, int], channels: int
) -> None:
    image = SMALL if channels == 3 else SMALL[..., :1] if channels == 1 else SMALL[..., 0]
    image = np.ascontiguousarray(image)
    out = crop_replicate(image, *window)
    expected = padded_window(image, *window)
    assert out.shape == expected.shape
    np.testing.assert_array_equal(out, expected)


@pytest.mark.parametrize(
    ("pos", "size"),
    [
        ((10.7, 20.2), (5, 6)),
        ((10.0, 20.0), (4, 4)),
        ((1.0, 1.0), (7, 8)),
        ((30.9, 40.5), (9, 3)),
        ((-2.5, 44.0), (6, 6)),
        ((5.0, 5.0), (0, 1)),
    ],
)
def test_bacf_patch_window_placement(pos: tuple[float, float], size: tuple[int, int]) -> None:
    """1-based rows floor(pos) + (1..s) - floor(s/2): first array index floor(pos) - floor(s/2);
    outside the image the border is replicated; sizes < 1 become 2 (release)."""
    image = coord_image(32, 45)
    sh, sw = (s if s >= 1 else 2 for s in size)
    out = bacf_patch(image, pos, size, (sh, sw))  # same size: no resampling
    top = math.floor(pos[0]) - sh // 2
    left = math.floor(pos[1]) - sw // 2
    rows = np.clip(np.arange(top, top + sh), 0, 31)
    cols = np.clip(np.arange(left, left + sw), 0, 44)
    np.testing.assert_array_equal(out[..., 0], np.broadcast_to(rows[:, None], (sh, sw)))
    np.testing.assert_array_equal(out[..., 1], np.broadcast_to(cols[None, :], (sh, sw)))
    np.testing.assert_array_equal(out, padded_window(image, top, left, sh, sw))


def test_bacf_patch_centre_pixel() -> None:
    """An odd window is centred on array index (floor(row), floor(col)), i.e. one pixel past the
    1-based position, exactly as the release's ``get_pixels``."""
    image = coord_image(40, 40)
    out = bacf_patch(image, (12.9, 20.3), (5, 5), (5, 5))
    # 1-based rows 12 + (1..5) - 2 = 11..15: the centre is 1-based 13, i.e. array index 12
    assert tuple(out[2, 2]) == (12, 20)


def test_bacf_patch_resizes_with_area_or_linear() -> None:
    rng = np.random.default_rng(6)
    image = rng.integers(0, 256, size=(60, 80, 3), dtype=np.uint8)
    window = crop_replicate(image, 30 - 10, 40 - 12, 20, 24)
    shrunk = bacf_patch(image, (30.0, 40.0), (20, 24), (10, 12))
    np.testing.assert_array_equal(
        shrunk, cv2.resize(window, (12, 10), interpolation=cv2.INTER_AREA)
    )
    grown = bacf_patch(image, (30.0, 40.0), (20, 24), (30, 36))
    np.testing.assert_array_equal(
        grown, cv2.resize(window, (36, 30), interpolation=cv2.INTER_LINEAR)
    )
    gray = np.ascontiguousarray(image[..., :1])
    assert bacf_patch(gray, (30.0, 40.0), (20, 24), (10, 12)).shape == (10, 12, 1)


@pytest.mark.parametrize(
    ("in_hw", "out_hw", "linear"),
    [
        ((40, 40), (15, 15), False),  # square, shrinking: both rules say area
        ((20, 20), (40, 40), True),  # square, enlarging: both rules say linear
        ((20, 20), (20, 21), True),  # 21 columns > 20 rows
        ((20, 20), (50, 20), False),  # enlarging, but 20 columns = 20 rows: area
        # non-square, where "area when shrinking" disagrees with the release:
        ((22, 48), (15, 32), True),  # shrinking (a DSST scale sample), but 32 columns > 22 rows
        ((10, 40), (8, 20), True),  # shrinking, 20 columns > 10 rows
        ((40, 10), (60, 12), False),  # enlarging (720 > 400 px), but 12 columns <= 40 rows
        ((48, 22), (32, 15), False),  # shrinking, 15 <= 48: area either way
    ],
)
def test_resize_auto_follows_the_release_rule(
    in_hw: tuple[int, int], out_hw: tuple[int, int], linear: bool
) -> None:
    """mexResize 'auto' as the release calls it: linear interpolation when the requested number
    of columns exceeds the input's number of rows, area otherwise (not "area when shrinking")."""
    rng = np.random.default_rng(14)
    patch = rng.integers(0, 256, size=(*in_hw, 3), dtype=np.uint8)
    assert (out_hw[1] > in_hw[0]) == linear
    out = resize_auto(patch, out_hw)
    assert out.shape == (*out_hw, 3)
    dsize = (out_hw[1], out_hw[0])
    want = cv2.INTER_LINEAR if linear else cv2.INTER_AREA
    other = cv2.INTER_AREA if linear else cv2.INTER_LINEAR
    np.testing.assert_array_equal(out, cv2.resize(patch, dsize, interpolation=want))
    # the two interpolations give different pixels here, so the rule is really exercised
    assert not np.array_equal(out, cv2.resize(patch, dsize, interpolation=other))
    # a single-channel patch keeps its trailing channel axis
    one = resize_auto(np.ascontiguousarray(patch[..., :1]), out_hw)
    assert one.shape == (*out_hw, 1)
    np.testing.assert_array_equal(one[..., 0], out[..., 0])


def test_resize_auto_same_size_is_the_identity() -> None:
    patch = np.random.default_rng(15).integers(0, 256, size=(9, 13, 3), dtype=np.uint8)
    assert resize_auto(patch, (9, 13)) is patch


# --------------------------------------------------------------------------- Fourier helpers


@pytest.mark.parametrize("shape", [(50, 50), (21, 34), (8, 5)])
def test_gaussian_label(shape: tuple[int, int]) -> None:
    sigma = 1.7
    y = gaussian_label(shape, sigma)
    assert y.shape == shape and y.dtype == np.float32
    assert y[0, 0] == 1.0 and np.unravel_index(np.argmax(y), shape) == (0, 0)
    # circularly symmetric about the origin: y[k] == y[-k]
    mirrored = np.roll(y[::-1, ::-1], (1, 1), axis=(0, 1))
    np.testing.assert_array_equal(y, mirrored)
    np.testing.assert_allclose(y[1, 0], math.exp(-0.5 / sigma**2), rtol=1e-6)
    np.testing.assert_allclose(y[-2, 2], math.exp(-0.5 * 8 / sigma**2), rtol=1e-6)
    rs, cs = signed_indices(shape[0]), signed_indices(shape[1])
    expected = np.exp(-0.5 * (rs[:, None] ** 2 + cs[None, :] ** 2) / sigma**2)
    np.testing.assert_allclose(y, expected, rtol=1e-6, atol=1e-30)
    # symmetric, hence a real spectrum
    spectrum = sfft.fft2(y.astype(np.float64))
    assert np.abs(spectrum.imag).max() < 1e-9 * np.abs(spectrum).max()


def test_signed_indices() -> None:
    assert signed_indices(5).tolist() == [0, 1, 2, -2, -1]
    assert signed_indices(4).tolist() == [0, 1, 2, -1]
    assert signed_indices(1).tolist() == [0]


def von_mises_map(
    shape: tuple[int, int], peak: tuple[float, float], amp: float, kappa: float = 12.0
) -> np.ndarray:
    """A smooth periodic bump with its (off-grid) maximum ``amp`` at ``peak`` (cells)."""
    h, w = shape
    r = np.arange(h)[:, None]
    c = np.arange(w)[None, :]
    return amp * np.exp(
        kappa * (np.cos(2 * np.pi * (r - peak[0]) / h) - 1)
        + kappa * (np.cos(2 * np.pi * (c - peak[1]) / w) - 1)
    )


@pytest.mark.parametrize(
    ("shape", "peak"),
    [
        ((50, 50), (3.3, -2.6)),
        ((50, 50), (0.45, 0.0)),
        ((41, 36), (-7.8, 12.25)),
        ((50, 50), (24.4, -24.7)),
    ],
)
@pytest.mark.parametrize("iterations", [5, 50])
def test_newton_peak_finds_the_sub_cell_maximum(
    shape: tuple[int, int], peak: tuple[float, float], iterations: int
) -> None:
    m = von_mises_map(shape, peak, amp=0.8)
    dr, dc, sind, value = newton_peak(m[None], sfft.fft2(m)[None], iterations)
    assert sind == 0
    # displacements are wrapped into [-n/2, n/2)
    exp_r = (peak[0] + shape[0] / 2) % shape[0] - shape[0] / 2
    exp_c = (peak[1] + shape[1] / 2) % shape[1] - shape[1] / 2
    assert abs(dr - exp_r) < 0.05 and abs(dc - exp_c) < 0.05, (dr, dc, peak)
    assert value == pytest.approx(0.8, rel=1e-3)
    assert value >= m.max()  # never worse than the integer peak


def test_newton_starts_from_matlabs_integer_peak() -> None:
    """The compiled start search breaks ties (and NaNs) as ``first_argmax_colmajor``: the
    first maximum in column-major order, as MATLAB's ``max`` then ``find`` do."""
    from arcf.fourier import _integer_peaks, first_argmax_colmajor

    rng = np.random.default_rng(21)
    for trial in range(300):
        maps = rng.integers(0, 3, (2, int(rng.integers(1, 7)), int(rng.integers(1, 7))))
        maps = maps.astype(np.float32)
        if trial % 4 == 0:
            maps[rng.random(maps.shape) < 0.15] = np.nan
        rows, cols, values = _integer_peaks(maps)
        for i in range(2):
            assert (rows[i], cols[i]) == first_argmax_colmajor(maps[i])
            assert np.array_equal(values[i], maps[i, rows[i], cols[i]], equal_nan=True)


def test_newton_peak_picks_the_best_map() -> None:
    shape = (40, 40)
    specs = [((2.3, 5.6), 0.5), ((-6.2, 1.4), 0.9), ((10.7, -3.3), 0.7)]
    maps = np.stack([von_mises_map(shape, p, a) for p, a in specs])
    dr, dc, sind, value = newton_peak(maps, sfft.fft2(maps), 50)
    assert sind == 1
    assert abs(dr + 6.2) < 0.05 and abs(dc - 1.4) < 0.05
    assert value == pytest.approx(0.9, rel=1e-3)
    # a sub-cell maximum beats a map whose integer samples are higher but whose true peak is not
    on_grid = von_mises_map(shape, (4.0, 4.0), 0.85)
    off_grid = von_mises_map(shape, (-9.5, 7.5), 0.86)  # integer samples reach only ~0.80
    assert on_grid.max() > off_grid.max()
    maps = np.stack([on_grid, off_grid])
    dr, dc, sind, value = newton_peak(maps, sfft.fft2(maps), 50)
    assert sind == 1 and abs(dr + 9.5) < 0.05 and abs(dc - 7.5) < 0.05


def _newton_numpy(response, spectrum, iterations):
    """``newton_peak`` as first written, one batched matrix product per term (BLAS sums)."""
    _, h, w = response.shape
    ky = signed_indices(h).astype(np.float64)
    kx = signed_indices(w).astype(np.float64)
    rf = spectrum.astype(np.complex128)
    starts = [np.unravel_index(np.argmax(m.T), m.T.shape)[::-1] for m in response]
    init_val = np.array([m[r, c] for m, (r, c) in zip(response, starts, strict=True)])
    rows, cols = np.array(starts).T
    init_y = 2 * np.pi * (np.mod(rows + (h - 1) // 2, h) - (h - 1) // 2) / h
    init_x = 2 * np.pi * (np.mod(cols + (w - 1) // 2, w) - (w - 1) // 2) / w
    py, px = init_y.copy(), init_x.copy()
    ky_pow, kx_pow = np.stack([ky**0, ky, ky * ky]), np.stack([kx**0, kx, kx * kx])

    def series(py, px):
        ey = np.exp(1j * py[:, None] * ky[None, :])[:, None, :] * ky_pow[None]
        ex = np.exp(1j * px[:, None] * kx[None, :])[:, :, None] * kx_pow.T[None]
        return ey @ (rf @ ex)

    for _ in range(iterations):
        m = series(py, px)
        gy, gx = -np.imag(m[:, 1, 0]), -np.imag(m[:, 0, 1])
        hyy = np.real(-m[:, 2, 0] + 1j * m[:, 0, 0])
        hxx = np.real(-m[:, 0, 2] + 1j * m[:, 0, 0])
        hxy = np.real(-m[:, 1, 1])
        det = hyy * hxx - hxy * hxy
        with np.errstate(divide="ignore", invalid="ignore"):
            ny, nx = py - (hxx * gy - hxy * gx) / det, px - (hyy * gx - hxy * gy) / det
        ok = np.isfinite(ny) & np.isfinite(nx)
        step = np.max(np.abs(np.where(ok, ny - py, 0)) + np.abs(np.where(ok, nx - px, 0)))
        py, px = np.where(ok, ny, py), np.where(ok, nx, px)
        if step < 1e-10:
            break
    val = np.real(series(py, px)[:, 0, 0]) / (h * w)
    worse = ~(val >= init_val)
    val, py, px = np.where(worse, init_val, val), np.where(worse, init_y, py), np.where(
        worse, init_x, px)
    best = int(np.argmax(val))
    wrap = lambda p, n: (np.mod(p + np.pi, 2 * np.pi) - np.pi) / (2 * np.pi) * n  # noqa: E731
    return wrap(py[best], h), wrap(px[best], w), best, val[best]


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("hermitian", [True, False])
def test_compiled_newton_equals_the_batched_products(seed: int, hermitian: bool) -> None:
    """The compiled iterations sum in another order than BLAS: the same scale, displacements
    within 1e-9 cells, on noisy multi-peak maps and on non-conjugate-symmetric spectra (the
    release's)."""
    rng = np.random.default_rng(seed)
    shape = (50, 50) if seed % 2 else (41, 36)
    maps = np.stack([von_mises_map(shape, tuple(rng.uniform(-15, 15, 2)), rng.uniform(0.5, 1))
                     for _ in range(5)])
    maps += 0.05 * rng.standard_normal(maps.shape)
    spectrum = sfft.fft2(maps)
    if not hermitian:
        spectrum = spectrum + 0.02 * spectrum.std() * (
            rng.standard_normal(spectrum.shape) + 1j * rng.standard_normal(spectrum.shape))
    for iterations in (5, 50):
        got = newton_peak(maps, spectrum, iterations)
        want = _newton_numpy(maps, spectrum, iterations)
        assert got[2] == want[2]
        np.testing.assert_allclose(got[:2], want[:2], rtol=0, atol=1e-9)
        assert got[3] == pytest.approx(want[3], rel=1e-12)


def test_spatial_response_hermitian_is_irfft2() -> None:
    rng = np.random.default_rng(8)
    for shape in ((12, 10), (9, 7)):
        m = rng.standard_normal((3, *shape))
        half = sfft.rfft2(m)
        np.testing.assert_allclose(spatial_response(half, shape, True), m, atol=1e-12)
        np.testing.assert_allclose(spatial_response(half[0], shape, True), m[0], atol=1e-12)
        np.testing.assert_array_equal(
            spatial_response(half, shape, True), sfft.irfft2(half, s=shape)
        )


@pytest.mark.parametrize("shape", [(12, 10), (9, 7)])
@pytest.mark.parametrize(("stack", "seed", "ignored", "used"), [
    # a 2-D map: the second half along columns is ignored (MATLAB's ifft2(..., 'symmetric')),
    # the second half along rows is used
    (None, 9, -1, -2),
    # a stack of maps (ARCF-H's scales): the redundant half is taken along the rows instead
    (5, 10, -2, -1),
], ids=["2d_keeps_first_half_of_columns", "stack_keeps_first_half_of_rows"])
def test_spatial_response_non_hermitian_keeps_one_half(
    shape: tuple[int, int], stack: int | None, seed: int, ignored: int, used: int,
) -> None:
    rng = np.random.default_rng(seed)
    m = rng.standard_normal(shape if stack is None else (stack, *shape))
    spectrum = sfft.fft2(m)
    garbage = rng.standard_normal(spectrum.shape) + 1j * rng.standard_normal(spectrum.shape)

    def second_half_garbled(axis: int) -> np.ndarray:
        out = spectrum.copy()
        half = [slice(None)] * out.ndim
        half[axis] = slice(out.shape[axis] // 2 + 1, None)
        out[tuple(half)] = garbage[tuple(half)]
        return out

    out = spatial_response(second_half_garbled(ignored), shape, False)
    assert out.shape == m.shape
    np.testing.assert_allclose(out, m, atol=1e-12)
    assert not np.allclose(spatial_response(second_half_garbled(used), shape, False), m)
    # on a Hermitian spectrum both conventions agree with the true inverse
    one, want = (spectrum, m) if stack is None else (spectrum[0], m[0])
    np.testing.assert_allclose(spatial_response(one, shape, False), want, atol=1e-12)


def test_peak_to_sidelobe() -> None:
    m = np.zeros((20, 20))
    assert peak_to_sidelobe(m, 2) == 0.0  # flat: finite, 0
    m = np.random.default_rng(11).standard_normal((20, 20)) * 0.01
    m[19, 0] = 1.0  # the main lobe wraps around the border
    side = np.ones((20, 20), bool)
    side[np.ix_([17, 18, 19, 0, 1], [18, 19, 0, 1, 2])] = False
    expected = (1.0 - m[side].mean()) / m[side].std()
    assert peak_to_sidelobe(m, 2) == pytest.approx(expected, rel=1e-12)
    # float32 maps viewed out of a stack of scales, as the tracker passes them
    stack = np.random.default_rng(12).random((3, 30, 26)).astype(np.float32)
    stack[1, 4, 25] = 3.0
    side = np.ones((30, 26), bool)
    side[np.ix_(np.arange(1, 8), np.arange(22, 29) % 26)] = False
    values = stack[1][side].astype(np.float64)
    expected = (3.0 - values.mean()) / values.std()
    assert peak_to_sidelobe(stack[1], 3) == pytest.approx(expected, rel=1e-12)
    assert peak_to_sidelobe(stack[1], 13) != 0.0  # 27 of 30 rows excluded: 3 rows remain
    assert peak_to_sidelobe(stack[1], 15) == 0.0  # a lobe wider than the map: no sidelobe
    with pytest.raises(ValueError):
        peak_to_sidelobe(stack, 2)


def test_feature_normalisation_fixes_the_energy_per_element() -> None:
    """ECO-style normalisation: each sample's squared features sum to H*W*D, whatever the
    contrast, so the filter's data term does not depend on image brightness."""
    rng = np.random.default_rng(7)
    patches = rng.integers(0, 256, size=(2, 64, 48, 3), dtype=np.uint8)
    patches[1] = patches[1] // 4  # a low-contrast sample
    plain = FeatureExtractor(("gray", "fhog"), 4, None)(patches, color=False)
    norm = FeatureExtractor(("gray", "fhog"), 4, None, normalize=True)(patches, color=False)
    n, d, h, w = norm.shape
    energy = (norm.astype(np.float64) ** 2).reshape(n, -1).sum(axis=1)
    np.testing.assert_allclose(energy, h * w * d, rtol=1e-4)
    # a positive rescaling per sample: same direction as the plain features
    for i in range(n):
        a, b = plain[i].ravel(), norm[i].ravel()
        assert np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)) > 0.99999

"""Tests of ``arcf.features.fhog`` against a slow reference written straight from the spec.

The reference follows Dollár's toolbox ``fhog`` (gradientMag + gradientHist with softBin=-1,
useHog=2) literally: per-pixel ``np.add.at`` scatter, float64 ``atan2`` (in degrees, see
``_ref_angle_degrees``) and explicit per-cell loops for the block normalisation, so that it is
easy to check by reading.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import arcf.features.fhog as fhog_module
from arcf.features.fhog import _orientation_bins, fhog

RNG = np.random.default_rng(12345)
TEX = 0.2357


# --------------------------------------------------------------------------------------------
# Reference implementation (slow, obviously correct)
# --------------------------------------------------------------------------------------------


def _ref_derivative(img: np.ndarray, axis: int) -> np.ndarray:
    """Toolbox gradient along ``axis``: central /2 inside, one-sided un-halved at the borders."""
    a = np.moveaxis(img, axis, 0)
    g = np.zeros_like(a)
    n = a.shape[0]
    for i in range(n):
        if n == 1:
            g[i] = 0.0
        elif i == 0:
            g[i] = a[1] - a[0]
        elif i == n - 1:
            g[i] = a[n - 1] - a[n - 2]
        else:
            g[i] = (a[i + 1] - a[i - 1]) / np.float32(2.0)
    return np.moveaxis(g, 0, axis)


def _ref_angle_degrees(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """atan2 in degrees, in [0, 360).  Degrees (not radians) so that the exactly representable
    directions that fall on bin boundaries (45, 90, 135, 270 degrees, ...) come out exact and
    round like in exact arithmetic (in radians, pi/4 * 12 / (2 pi) + 0.5 can give 1.999...)."""
    theta = np.degrees(np.arctan2(np.asarray(gy, np.float64), np.asarray(gx, np.float64)))
    theta[theta < 0] += 360.0
    return theta


def ref_fhog(image: np.ndarray, cell: int = 4, n_orients: int = 9, clip: float = 0.2) -> np.ndarray:
    """One (H, W) or (H, W, C) image -> (H // cell, W // cell, 3 n + 4), per the spec."""
    img = np.asarray(image, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    height, width, _ = img.shape
    n_bins = 2 * n_orients

    # 1. gradient of the channel with the largest squared magnitude (first on ties)
    gx_all = _ref_derivative(img, 1)
    gy_all = _ref_derivative(img, 0)
    m2_all = gx_all * gx_all + gy_all * gy_all
    best = np.argmax(m2_all, axis=2)[..., None]  # argmax returns the first maximum
    gx = np.take_along_axis(gx_all, best, 2)[..., 0].astype(np.float64)
    gy = np.take_along_axis(gy_all, best, 2)[..., 0].astype(np.float64)
    mag = np.sqrt(np.take_along_axis(m2_all, best, 2)[..., 0]).astype(np.float64)
    theta = _ref_angle_degrees(gx, gy)

    # 2. histogram: hard orientation, bilinear spatial voting
    hb, wb = height // cell, width // cell
    h0, w0 = hb * cell, wb * cell
    r1 = np.zeros((hb, wb, n_bins))
    ys, xs = np.mgrid[0:h0, 0:w0]
    ys, xs = ys.ravel(), xs.ravel()
    o = (theta[ys, xs] * n_bins / 360 + 0.5).astype(int)
    o[o >= n_bins] = 0
    m = mag[ys, xs] / cell**2
    xb = (xs + 0.5) / cell - 0.5
    yb = (ys + 0.5) / cell - 0.5
    xb0 = np.floor(xb).astype(int)
    yb0 = np.floor(yb).astype(int)
    xd = xb - xb0
    yd = yb - yb0
    for cy, wy in ((yb0, 1 - yd), (yb0 + 1, yd)):
        for cx, wx in ((xb0, 1 - xd), (xb0 + 1, xd)):
            ok = (cy >= 0) & (cy < hb) & (cx >= 0) & (cx < wb)
            np.add.at(r1, (cy[ok], cx[ok], o[ok]), (m * wy * wx)[ok])
    r1[0] *= 8 / 7
    r1[-1] *= 8 / 7
    r1[:, 0] *= 8 / 7
    r1[:, -1] *= 8 / 7

    # 3. contrast-insensitive histogram, 4. block normalisers
    r2 = r1[..., :n_orients] + r1[..., n_orients:]
    energy = (r2**2).sum(-1)
    eps = 1e-4 / 4 / cell**4
    nbr, nbc = max(hb - 1, 1), max(wb - 1, 1)
    block = np.zeros((nbr, nbc))
    for i in range(nbr):
        for j in range(nbc):
            s = sum(
                energy[i + di, j + dj]
                for di in (0, 1)
                for dj in (0, 1)
                if i + di < hb and j + dj < wb
            )
            block[i, j] = 1 / np.sqrt(s + eps)
    norm = np.zeros((hb + 1, wb + 1))
    for a in range(hb + 1):
        for b in range(wb + 1):
            norm[a, b] = block[min(max(a - 1, 0), nbr - 1), min(max(b - 1, 0), nbc - 1)]

    # 5. channels
    out = np.zeros((hb, wb, 3 * n_orients + 4))
    for i in range(hb):
        for j in range(wb):
            ns = (norm[i + 1, j + 1], norm[i, j + 1], norm[i + 1, j], norm[i, j])
            for k, nk in enumerate(ns):
                t1 = np.minimum(r1[i, j] * nk, clip)
                t2 = np.minimum(r2[i, j] * nk, clip)
                out[i, j, :n_bins] += 0.5 * t1
                out[i, j, n_bins : 3 * n_orients] += 0.5 * t2
                out[i, j, 3 * n_orients + k] = TEX * t1.sum()
    return out


def assert_close(actual: np.ndarray, expected: np.ndarray) -> None:
    np.testing.assert_allclose(actual, expected, rtol=1e-5, atol=1e-6)


def random_image(shape: tuple[int, ...]) -> np.ndarray:
    return RNG.integers(0, 256, shape, dtype=np.uint8)


# --------------------------------------------------------------------------------------------
# Agreement with the reference
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cell", [1, 2, 3, 4])
@pytest.mark.parametrize("shape", [(37, 53), (37, 53, 3), (24, 16, 3), (13, 9), (40, 44, 1)])
def test_matches_reference(shape: tuple[int, ...], cell: int) -> None:
    img = random_image(shape)
    out = fhog(img, cell_size=cell)
    assert out.dtype == np.float32
    assert out.shape == (shape[0] // cell, shape[1] // cell, 31)
    assert_close(out, ref_fhog(img, cell))


def test_matches_reference_natural_like_image() -> None:
    # Smooth structure (large flat areas, many exactly horizontal / vertical gradients and
    # colour channels with tied magnitudes) exercises tie rules that noise rarely hits.
    y, x = np.mgrid[0:48, 0:60]
    img = np.stack([(x // 7) * 20, (y // 5) * 17, ((x + y) // 6) * 9], axis=-1)
    img = np.clip(img, 0, 255).astype(np.uint8)
    img[10:20, 30:45] = 200
    for cell in (2, 4):
        assert_close(fhog(img, cell), ref_fhog(img, cell))


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32])
def test_other_dtypes(dtype: type) -> None:
    # Quarter-integer values keep the exhaustively verified exactness of the binning.
    img = (RNG.integers(0, 1021, (29, 34, 3)) / 4).astype(dtype)
    assert_close(fhog(img), ref_fhog(img))


@pytest.mark.parametrize("n_orients", [4, 6, 8])
def test_other_orientation_counts(n_orients: int) -> None:
    img = random_image((30, 26, 3))
    out = fhog(img, 4, n_orients=n_orients, clip=0.3)
    assert out.shape == (7, 6, 3 * n_orients + 4)
    assert_close(out, ref_fhog(img, 4, n_orients, clip=0.3))


def test_batch_matches_single_calls() -> None:
    imgs = random_image((5, 37, 53, 3))
    out = fhog(imgs)
    assert out.shape == (5, 9, 13, 31)
    for i in range(5):
        np.testing.assert_array_equal(out[i], fhog(imgs[i]))
        assert_close(out[i], ref_fhog(imgs[i]))


def test_batch_split_into_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    imgs = random_image((7, 30, 26, 3))
    whole = fhog(imgs, 3)
    assert fhog_module._chunk_size(30, 26, 10, 8, 9) >= 7  # the call above used one chunk
    for step in (1, 3):  # chunks of 1 / of 3, 3 and 1 images
        monkeypatch.setattr(fhog_module, "_chunk_size", lambda *args, step=step: step)
        np.testing.assert_array_equal(fhog(imgs, 3), whole)
    assert_close(whole[6], ref_fhog(imgs[6], 3))


def test_batch_of_tiny_patches_small_cells() -> None:
    imgs = random_image((33, 32, 16, 3))
    for cell in (1, 2, 3, 4):
        out = fhog(imgs, cell)
        assert out.shape == (33, 32 // cell, 16 // cell, 31)
        for i in (0, 17, 32):
            assert_close(out[i], ref_fhog(imgs[i], cell))


def test_multiple_leading_dims_and_grey_batch() -> None:
    imgs = random_image((2, 3, 20, 24, 1))
    out = fhog(imgs)
    assert out.shape == (2, 3, 5, 6, 31)
    assert_close(out[1, 2], ref_fhog(imgs[1, 2, ..., 0]))


@pytest.mark.parametrize(
    ("shape", "cell"),
    [
        ((4, 20), 4),
        ((22, 5), 4),
        ((7, 7), 4),
        ((1, 9), 1),
        ((3, 2), 1),
        ((12, 4), 2),
        ((4, 12), 1),
        ((5, 3), 1),
        ((3, 5), 1),
        ((1, 1), 1),
    ],
)
def test_single_row_or_column_of_cells(shape: tuple[int, int], cell: int) -> None:
    img = random_image(shape)
    out = fhog(img, cell)
    assert out.shape == (shape[0] // cell, shape[1] // cell, 31)
    assert np.isfinite(out).all()
    assert_close(out, ref_fhog(img, cell))


def test_image_smaller_than_a_cell() -> None:
    assert fhog(random_image((3, 40)), 4).shape == (0, 10, 31)
    assert fhog(random_image((2, 3, 40, 3)), 4).shape == (2, 0, 10, 31)


def test_input_layout_rules() -> None:
    img = random_image((20, 24, 3))
    np.testing.assert_array_equal(fhog(img), fhog(img[None])[0])
    with pytest.raises(ValueError):
        fhog(random_image((4, 20, 24)))  # ambiguous: use (N, H, W, 1) for a grey batch
    with pytest.raises(ValueError):
        fhog(random_image((24,)))


def test_reused_buffers_across_shapes_and_threads() -> None:
    # The implementation keeps per-thread scratch buffers; interleave shapes and threads.
    inputs = [
        random_image((3, 64, 48, 3)),
        random_image((20, 28)),
        random_image((33, 32, 16, 3)),
        random_image((1, 64, 48, 3)),
    ]
    cells = [4, 2, 3, 4]
    expected = [fhog(x, c).copy() for x, c in zip(inputs, cells, strict=True)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        for _ in range(3):
            results = list(pool.map(fhog, inputs * 2, cells * 2))
            for got, want in zip(results, expected * 2, strict=True):
                np.testing.assert_array_equal(got, want)
    # Returned arrays never alias the scratch buffers.
    first = fhog(inputs[0], 4)
    snapshot = first.copy()
    fhog(inputs[2], 3)
    fhog(inputs[0][:, ::-1], 4)
    np.testing.assert_array_equal(first, snapshot)


# --------------------------------------------------------------------------------------------
# Orientation binning
# --------------------------------------------------------------------------------------------


def _ref_bins(gx: np.ndarray, gy: np.ndarray, n_orients: int) -> np.ndarray:
    theta = _ref_angle_degrees(gx, gy)
    o = (theta * (2 * n_orients) / 360 + 0.5).astype(int)
    o[o >= 2 * n_orients] = 0
    return o


def test_orientation_bins_exact_on_the_8bit_gradient_lattice() -> None:
    # Every (doubled) gradient an 8-bit image can produce: integers in [-510, 510]^2.
    v = np.arange(-510, 511, dtype=np.float32)
    gx, gy = (a.ravel() for a in np.meshgrid(v, v))
    nonzero = (gx != 0) | (gy != 0)
    got = _orientation_bins(gx, gy, 9)
    np.testing.assert_array_equal(got[nonzero], _ref_bins(gx, gy, 9)[nonzero])


@pytest.mark.parametrize("n_orients", [2, 3, 4, 5, 6, 8, 9, 12])
def test_orientation_bins_other_counts(n_orients: int) -> None:
    v = np.arange(-60, 61, dtype=np.float32) / 2
    gx, gy = (a.ravel() for a in np.meshgrid(v, v))
    nonzero = (gx != 0) | (gy != 0)
    got = _orientation_bins(gx, gy, n_orients)
    np.testing.assert_array_equal(got[nonzero], _ref_bins(gx, gy, n_orients)[nonzero])


def test_axis_aligned_gradients_and_signed_zeros() -> None:
    z = np.float32(0.0)
    nz = np.float32(-0.0)
    gx = np.array([1, -1, z, nz, z, nz, 1, -1, 1, -1], np.float32)
    gy = np.array([z, z, 1, 1, -1, -1, nz, nz, 1, -1], np.float32)
    # 0, 180, 90 (the boundary 4.5 rounds up to 5), 270 (13.5 -> 14), 45 (2.25 -> 2), 225
    expected = [0, 9, 5, 5, 14, 14, 0, 9, 2, 11]
    np.testing.assert_array_equal(_orientation_bins(gx, gy, 9), expected)


# --------------------------------------------------------------------------------------------
# Invariants and sanity checks
# --------------------------------------------------------------------------------------------


def test_value_bounds() -> None:
    clip = 0.2
    out = fhog(random_image((6, 48, 40, 3)), 4, clip=clip)
    assert (out >= 0).all()
    # Orientation channels: 0.5 * 4 normalisers * clip.
    assert out[..., :27].max() <= 0.5 * 4 * clip + 1e-6
    # Texture channel: 0.2357 * sum_o min(R1[o] n, clip) <= 0.2357 * min(18 clip, 3), since
    # sum_o R1[o] = sum_o R2[o] <= 3 ||R2|| (Cauchy-Schwarz) and n <= 1 / ||R2|| (the block
    # contains the cell).  For clip = 0.2 that is 1/sqrt(2), below the naive 18 * clip bound.
    bound = TEX * min(18 * clip, 3.0)
    assert out[..., 27:].max() <= bound + 1e-6
    # Noise saturates some bins, so the bounds are not vacuous.
    assert out[..., :27].max() > 0.5 * clip


def test_constant_image_gives_zeros() -> None:
    for img in (np.full((32, 36, 3), 77, np.uint8), np.zeros((20, 20), np.float32)):
        out = fhog(img)
        assert out.shape[-1] == 31
        assert not out.any()


@pytest.mark.parametrize(
    ("ramp", "sensitive", "insensitive"),
    [
        ("right", 0, 0),  # intensity grows with x: gradient direction 0
        ("left", 9, 0),  # direction 180 degrees
        ("down", 5, 5),  # direction +90 (rows grow downwards): 4.5 rounds up to bin 5
        ("up", 14, 5),  # direction 270: 13.5 rounds up to 14
        ("diagonal", 2, 2),  # 45 degrees: 2.25 -> bin 2
    ],
)
def test_ramp_energy_in_expected_bins(ramp: str, sensitive: int, insensitive: int) -> None:
    y, x = np.mgrid[0:40, 0:48].astype(np.float32)
    img = {"right": 2 * x, "left": 2 * (47 - x), "down": 3 * y, "up": 3 * (39 - y)}.get(ramp, x + y)
    out = fhog(img, 4)
    assert (out[..., sensitive] > 0.05).all()
    assert (out[..., 18 + insensitive] > 0.05).all()
    others = np.delete(out[..., :27], [sensitive, 18 + insensitive], axis=-1)
    assert not others.any()
    assert (out[..., 27:] > 0).all()


def test_equal_channels_equal_grey() -> None:
    grey = random_image((36, 44))
    colour = np.repeat(grey[..., None], 3, axis=-1)
    np.testing.assert_array_equal(fhog(colour, 4), fhog(grey, 4))
    np.testing.assert_array_equal(fhog(colour, 3), fhog(grey, 3))


def _no_vertical_gradient_image(height: int, width: int) -> np.ndarray:
    # Adding 0.1 * x to integers makes every horizontal difference non-zero, so no gradient
    # lies exactly on the 90/270 degree bin boundaries, where mirroring changes the rounding.
    x = np.arange(width, dtype=np.float64)
    return random_image((height, width, 3)) + 0.1 * x[None, :, None]


@pytest.mark.parametrize("cell", [2, 4])
def test_left_right_flip_maps_bins(cell: int) -> None:
    img = _no_vertical_gradient_image(10 * cell, 12 * cell)  # multiples of the cell size
    out = fhog(img, cell)
    flipped = fhog(img[:, ::-1], cell)[:, ::-1]
    # theta -> 180 - theta: sensitive o -> (9 - o) % 18, insensitive o -> (9 - o) % 9; the
    # normalising blocks swap left/right: (own, up, left, up-left) -> (left, up-left, own, up).
    o = np.arange(18)
    assert_close(flipped[..., (9 - o) % 18], out[..., :18])
    o = np.arange(9)
    assert_close(flipped[..., 18 + (9 - o) % 9], out[..., 18:27])
    assert_close(flipped[..., [29, 30, 27, 28]], out[..., 27:])


@pytest.mark.parametrize("cell", [3, 4])
def test_up_down_flip_maps_bins(cell: int) -> None:
    img = _no_vertical_gradient_image(9 * cell, 7 * cell)
    out = fhog(img, cell)
    flipped = fhog(img[::-1], cell)[::-1]
    # theta -> -theta: sensitive o -> (18 - o) % 18, insensitive o -> (9 - o) % 9; blocks swap
    # up/down: (own, up, left, up-left) -> (up, own, up-left, left).
    o = np.arange(18)
    assert_close(flipped[..., (18 - o) % 18], out[..., :18])
    o = np.arange(9)
    assert_close(flipped[..., 18 + (9 - o) % 9], out[..., 18:27])
    assert_close(flipped[..., [28, 27, 30, 29]], out[..., 27:])


def test_flip_test_is_sensitive_to_vertical_gradients() -> None:
    # Guard for the helper above: with exactly vertical gradients the mirror rule does NOT hold
    # (bin 5 stays 5 instead of becoming 4), which is why those are avoided.
    y = np.mgrid[0:16, 0:16][0].astype(np.float32)
    out = fhog(3 * y, 4)
    flipped = fhog((3 * y)[:, ::-1], 4)[:, ::-1]
    assert out[..., 5].all()
    assert flipped[..., 5].all()
    assert not flipped[..., 4].any()

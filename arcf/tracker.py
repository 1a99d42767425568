"""The ARCF tracker: ``init(frame, box)`` then ``update(frame) -> TrackResult``.

One class runs all three presets. The per-frame loop reads like the paper (Fig. 2):

1. :meth:`ARCFTracker._detect` — features at the previous position (and scales), correlation with
   the filter ĝ, sub-cell peak by Newton's method, new position and scale;
2. :meth:`ARCFTracker._aberrance` — the response map M_k, the previous map shifted onto it,
   the map difference of Eq. 2, and the aberrance target for training;
3. :meth:`ARCFTracker._train` — features at the new position, running model, ADMM (Eq. 5–17).

Coordinates: boxes are ``(x, y, w, h)`` in the datasets' 1-based pixel frame (the pixel at array
index [0, 0] has coordinates (1, 1)); internally positions are (row, col) in that same frame so
that the release's floor/round rules apply unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import scipy.fft as sfft

from .aberrance import (
    map_difference,
    paper_target,
    peak_index,
    release_target,
    shift_to,
    symmetric_half,
)
from .admm import Crop, solve_filter
from .errors import InvalidBoxError, InvalidFrameError, NotInitializedError, UnknownPresetError
from .features.extract import FeatureExtractor
from .features.fhog import Arithmetic as FhogArithmetic
from .features.patches import matlab_round, pyramid_windows, release_windows
from .features.sse import load_sse_tables
from .fourier import (
    correlate,
    full_spectrum,
    gaussian_label,
    hann2d,
    newton_peak,
    peak_to_sidelobe,
    shift_spectrum,
    spatial_response,
)
from .presets import TrackerParams, make_params
from .scale import DSSTScaleFilter, scale_limits, search_scale_factors

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class TrackResult:
    """What the tracker reports for one frame.

    ``peak`` is the response maximum at the sub-cell peak and ``psr`` the peak-to-sidelobe ratio
    of the response map: both are confidences (low when the target is lost or occluded).
    ``aberrance`` is the response-map difference of Eq. 2 (Euclidean norm of the previous map,
    shifted onto the current peak, minus the current map); ``aberrance_release`` is the same
    difference measured as the release does (largest singular value), comparable with the
    published ``map_diff`` files. Both are 0 on the first frame.
    """

    box: Box
    peak: float
    psr: float
    aberrance: float
    aberrance_release: float
    scale: float
    frame_index: int

    @property
    def confidence(self) -> float:
        """The response peak, the usual DCF confidence.

        Its scale is set by the filter's regularisation, not normalised: for these presets it sits
        around 0.01-0.05 while tracking well. Compare it with the same track's recent history (or
        use ``psr``, which is scale-free) rather than with a fixed absolute threshold.
        """
        return self.peak


class ARCFTracker:
    """ARCF-H, ARCF-HC or BACF, depending on its :class:`~arcf.presets.TrackerParams`."""

    def __init__(self, params: TrackerParams, colornames_path: str | Path | None = None) -> None:
        self.params = params
        self._colornames_path = str(colornames_path) if colornames_path is not None else None
        self._initialized = False
        #: Paper formulation (or γ = 0, or the release's target made conjugate symmetric):
        #: filters are real in space, half spectra suffice.
        self._hermitian = (
            params.aberrance == "paper" or params.gamma == 0 or params.spectra == "half"
        )
        #: fHOG's arithmetic: the preset's mode, or a CPU's measured SSE tables replayed.
        self._fhog_arithmetic: FhogArithmetic = params.fhog_arithmetic
        if params.fhog_sse_table is not None:
            try:
                self._fhog_arithmetic = load_sse_tables(params.fhog_sse_table)
            except (OSError, ValueError) as exc:
                raise UnknownPresetError(f"fhog_sse_table: {exc}") from exc

    # ------------------------------------------------------------------ public API
    @property
    def initialized(self) -> bool:
        return self._initialized

    def init(self, frame: np.ndarray, box: Box | Any) -> TrackResult:
        """Start (or restart) tracking ``box`` in ``frame``; returns the first frame's result.

        A failed (re-)initialisation leaves the tracker exactly as it was, so a bad request on a
        live stream does not break the target already being tracked.
        """
        snapshot = dict(self.__dict__)
        try:
            return self._init(frame, box)
        except BaseException:
            self.__dict__.clear()
            self.__dict__.update(snapshot)
            raise

    def _init(self, frame: np.ndarray, box: Box | Any) -> TrackResult:
        image, color = self._frame_for_init(frame)
        x, y, w, h = validate_box(box, image.shape[:2])
        self._color = color
        self._image_hw = image.shape[:2]
        if self.params.sizing == "filter_max_area":
            self._configure_bacf(x, y, w, h)
        else:
            self._configure_eco(x, y, w, h)
        self._extractor = FeatureExtractor(
            self.params.features,
            self._cell,
            self._colornames_path,
            self.params.normalize_features,
            self._fhog_arithmetic,
        )
        self._extractor.prepare(color)
        self._window = hann2d(self._use_sz)
        self._yf = self._fwd(gaussian_label(self._use_sz, self._sigma))
        self._crop = Crop(self._use_sz, self._small_filter_sz)
        self._frame_index = 0

        xf = self._training_sample(image)
        self._model_xf = xf
        self._g_f = self._solve(None)
        first = spatial_response(
            correlate(self._g_f, self._model_xf[None])[0], self._use_sz, self._hermitian
        )
        self._m_prev = sfft.fftshift(first)
        self._p_prev = peak_index(self._m_prev)
        if self._scale_filter is not None:
            self._scale_filter.update(image, self._pos, self._base_target_sz, self._csf, True)
        self._initialized = True
        return TrackResult(
            box=self._box(),
            peak=float(first.max()),
            psr=peak_to_sidelobe(first, self._psr_radius),
            aberrance=0.0,
            aberrance_release=0.0,
            scale=self._csf / self._csf0,
            frame_index=0,
        )

    def update(self, frame: np.ndarray) -> TrackResult:
        """Track into the next frame."""
        if not self._initialized:
            raise NotInitializedError("call init(frame, box) before update(frame)")
        image = self._frame_for_update(frame)
        self._frame_index += 1
        response, peak = self._detect(image)
        frob, spectral, target_f = self._aberrance(response)
        if self.params.training_sample == "shift":
            sample = self._shifted_sample()
        else:
            sample = self._training_sample(image)
        # x̂ <- (1 - η) x̂ + η x̂_t, in place: the same products and sum, no new model array
        sample *= self.params.learning_rate
        self._model_xf *= 1 - self.params.learning_rate
        self._model_xf += sample
        self._g_f = self._solve(target_f)
        if self._scale_filter is not None:
            self._scale_filter.update(image, self._pos, self._base_target_sz, self._csf, False)
        return TrackResult(
            box=self._box(),
            peak=peak,
            psr=peak_to_sidelobe(response, self._psr_radius),
            aberrance=frob,
            aberrance_release=spectral,
            scale=self._csf / self._csf0,
            frame_index=self._frame_index,
        )

    # ------------------------------------------------------------------ configuration
    def _configure_bacf(self, x: float, y: float, w: float, h: float) -> None:
        """ARCF-H / BACF sizing: feature grid of at most ``filter_max_area`` cells."""
        p = self.params
        init_sz = np.array([max(math.floor(h), 1), max(math.floor(w), 1)], dtype=np.float64)
        self._pos = (
            float(math.floor(y + math.floor(h / 2))),
            float(math.floor(x + math.floor(w / 2))),
        )
        cell = p.cell_size
        search_area = float(np.prod(init_sz / cell * p.search_area_scale))
        if search_area < p.cell_selection_thresh * p.filter_max_area:
            # tiny targets: a smaller cell keeps enough cells in the grid (release, from BACF)
            need = np.prod(init_sz * p.search_area_scale) / (
                p.cell_selection_thresh * p.filter_max_area
            )
            cell = min(cell, max(1, math.ceil(math.sqrt(need))))
            search_area = float(np.prod(init_sz / cell * p.search_area_scale))
        csf = math.sqrt(search_area / p.filter_max_area) if search_area > p.filter_max_area else 1.0
        base = init_sz / csf
        side = math.sqrt(float(np.prod(base * p.search_area_scale)))
        sz = matlab_round(side / cell) * cell
        sz = max(sz, 2 * cell)
        self._cell = cell
        self._sample_sz = sz  # pixels at the working resolution (square)
        self._use_sz = (sz // cell, sz // cell)
        self._finish_configuration(base, csf, (float(sz), float(sz)))
        self._scale_factors = search_scale_factors(p.n_scales, p.scale_step)
        self._scale_filter = None
        self._min_scale, self._max_scale = scale_limits(
            p.scale_step, (sz, sz), self._base_target_sz, self._image_hw
        )

    def _configure_eco(self, x: float, y: float, w: float, h: float) -> None:
        """ARCF-HC sizing: search region rescaled to a pixel area in [150², 200²] (ECO/STRCF)."""
        p = self.params
        target = np.array([h, w], dtype=np.float64)
        self._pos = (y + (h - 1) / 2, x + (w - 1) / 2)
        search_area = float(np.prod(target * p.search_area_scale))
        if search_area > p.max_image_sample_size:
            csf = math.sqrt(search_area / p.max_image_sample_size)
        elif search_area < p.min_image_sample_size:
            csf = math.sqrt(search_area / p.min_image_sample_size)
        else:
            csf = 1.0
        base = target / csf
        self._cell = cell = p.cell_size
        side = math.sqrt(float(np.prod(base * p.search_area_scale)))
        support = max(matlab_round(side / cell) * cell, 2 * cell)
        self._sample_sz = support
        self._use_sz = (support // self._cell, support // self._cell)
        self._finish_configuration(base, csf, (float(support), float(support)))
        self._scale_factors = np.ones(1)
        sf = p.scale_filter
        self._scale_filter = DSSTScaleFilter(
            sf, (float(h), float(w)), self._fhog_arithmetic, p.sampling
        )
        self._min_scale, self._max_scale = scale_limits(
            sf.scale_step, (support, support), self._base_target_sz, self._image_hw
        )

    def _finish_configuration(
        self, base: np.ndarray, csf: float, sample_px: tuple[float, float]
    ) -> None:
        cell = self._cell
        self._csf = self._csf0 = csf
        self._base_target_sz = (float(base[0]), float(base[1]))
        cells = np.floor(base / cell)
        self._sigma = math.sqrt(max(float(np.prod(cells)), 1.0)) * self.params.output_sigma_factor
        self._small_filter_sz = (
            int(np.clip(cells[0], 1, self._use_sz[0])),
            int(np.clip(cells[1], 1, self._use_sz[1])),
        )
        self._cell_px = (sample_px[0] / self._use_sz[0], sample_px[1] / self._use_sz[1])
        self._psr_radius = max(2, math.ceil(3 * self._sigma))

    # ------------------------------------------------------------------ the three steps
    def _detect(self, image: np.ndarray) -> tuple[np.ndarray, float]:
        """Step 1: locate the target; updates position and scale. Returns (map, peak value)."""
        p = self.params
        sample_pos = self._sample_pos()
        patches = self._patches(image, sample_pos, self._scale_factors)
        if p.training_sample == "shift":
            maps = self._extractor(patches, self._color, bgr=True)  # unwindowed, for training
            xtf = self._fwd(maps * self._window)  # (S, D, H, W')
        else:
            xtf = self._fwd(self._extractor(patches, self._color, self._window, bgr=True))
        rf = correlate(self._g_f, xtf)  # (S, H, W')
        if rf.shape[0] == 1:
            response = spatial_response(rf[0], self._use_sz, self._hermitian)[None]
        else:
            response = spatial_response(rf, self._use_sz, self._hermitian)
        if not self._hermitian:
            full_rf = rf
        elif p.spectra == "half":  # what the release's Newton reads: the correlation's spectrum
            full_rf = full_spectrum(rf, self._use_sz[1], np.complex128)  # Newton's precision
        else:  # bit for bit the earlier formulation (the release-compatible BACF)
            full_rf = sfft.fft2(response)
        disp_r, disp_c, sind, peak = newton_peak(response, full_rf, p.newton_iterations)

        factor = float(self._scale_factors[sind])
        px_per_cell = (self._cell_px[0] * self._csf * factor, self._cell_px[1] * self._csf * factor)
        step_r = disp_r * px_per_cell[0]
        step_c = disp_c * px_per_cell[1]
        if p.round_translation:
            step_r, step_c = float(matlab_round(step_r)), float(matlab_round(step_c))
        self._pos = (sample_pos[0] + step_r, sample_pos[1] + step_c)
        if p.training_sample == "shift":
            # what "shift" training reuses: this sample, and where the new position lies in it
            self._detection_maps = maps[sind]
            new_pos = self._sample_pos()
            self._detection_shift = (
                (new_pos[0] - sample_pos[0]) / px_per_cell[0],
                (new_pos[1] - sample_pos[1]) / px_per_cell[1],
            )
        if self._scale_filter is not None:
            factor = self._scale_filter.estimate(image, self._pos, self._base_target_sz, self._csf)
        self._csf = float(np.clip(self._csf * factor, self._min_scale, self._max_scale))
        return response[sind], peak

    def _aberrance(
        self, response: np.ndarray
    ) -> tuple[float, float, np.ndarray | None]:
        """Step 2: map difference (Eq. 2) and the aberrance target of the next ADMM solve."""
        m_curr = sfft.fftshift(response)
        p_curr = peak_index(m_curr)
        m_prev_shifted = shift_to(self._m_prev, self._p_prev, p_curr)
        frob, spectral = map_difference(m_prev_shifted, m_curr)
        target_f: np.ndarray | None = None
        if self.params.gamma:
            if self.params.aberrance == "paper":
                target_f = self._fwd(paper_target(self._m_prev, self._p_prev).astype(np.float32))
            elif self._hermitian:
                target_f = symmetric_half(release_target(m_prev_shifted)).astype(np.complex64)
            else:
                target_f = release_target(m_prev_shifted).astype(np.complex64)
        self._m_prev, self._p_prev = m_curr, p_curr
        return frob, spectral, target_f

    def _training_sample(self, image: np.ndarray) -> np.ndarray:
        """Step 3a: windowed features at the new position and scale, in the Fourier domain."""
        patch = self._patches(image, self._sample_pos(), (1.0,))
        return self._fwd(self._extractor(patch, self._color, self._window, bgr=True)[0])

    def _shifted_sample(self) -> np.ndarray:
        """Step 3a with ``training_sample="shift"``: the detection sample of the chosen scale
        moved onto the new position, by whole cells in space (so that the cosine window stays
        centred) and by the remaining fraction of a cell in the Fourier domain."""
        dr, dc = self._detection_shift
        whole = (int(np.round(dr)), int(np.round(dc)))
        maps = np.roll(self._detection_maps, (-whole[0], -whole[1]), axis=(-2, -1))
        xf = self._fwd(maps * self._window)
        return shift_spectrum(xf, (dr - whole[0], dc - whole[1]), self._use_sz)

    def _solve(self, target_f: np.ndarray | None) -> np.ndarray:
        """Step 3b: the filter ĝ from the running model by ADMM."""
        p = self.params
        g_f, _ = solve_filter(
            self._model_xf,
            self._yf,
            target_f,
            gamma=p.gamma,
            admm_lambda=p.admm_lambda,
            iterations=p.admm_iterations,
            crop=self._crop,
            hermitian=self._hermitian,
            mu_init=p.mu_init,
            mu_scale_step=p.mu_scale_step,
            mu_max=p.mu_max,
        )
        return g_f

    # ------------------------------------------------------------------ helpers
    def _sample_pos(self) -> tuple[float, float]:
        """Where windows are cut: the position rounded to a pixel (ARCF-H's already is)."""
        return float(matlab_round(self._pos[0])), float(matlab_round(self._pos[1]))

    def _patches(
        self, image: np.ndarray, pos: tuple[float, float], factors: Any
    ) -> np.ndarray:
        """The search windows at relative scales ``factors``, resized to the working size.

        (N, S, S, C) uint8 in the frame's BGR order (the feature extractor reads them as the
        release's RGB), S = ``self._sample_sz``; each window's side is ``round(S * csf *
        factor)`` source pixels (release: ``get_pixels``).
        """
        sides = [matlab_round(self._sample_sz * self._csf * f) for f in factors]
        out_hw = (self._sample_sz, self._sample_sz)
        if self.params.sampling == "pyramid":
            return pyramid_windows(image, pos, [(s, s) for s in sides], out_hw)
        return release_windows(image, pos, [(s, s) for s in sides], out_hw)

    def _fwd(self, maps: np.ndarray) -> np.ndarray:
        return sfft.rfft2(maps) if self._hermitian else sfft.fft2(maps)

    def _box(self) -> Box:
        th = self._base_target_sz[0] * self._csf
        tw = self._base_target_sz[1] * self._csf
        r, c = self._pos
        if self.params.whole_pixel_boxes:
            x, y = c - (tw - 1) / 2, r - (th - 1) / 2
            return (
                float(matlab_round(x)),
                float(matlab_round(y)),
                float(max(matlab_round(tw), 1)),
                float(max(matlab_round(th), 1)),
            )
        if self.params.sizing == "filter_max_area":
            # the release floors the size; a collapsed scale would give a 0-px side, which is
            # no box at all (nothing can be re-initialised from it), so report at least 1 px
            th, tw = float(max(math.floor(th), 1)), float(max(math.floor(tw), 1))
            return (c - math.floor(tw / 2), r - math.floor(th / 2), tw, th)
        return (c - (tw - 1) / 2, r - (th - 1) / 2, tw, th)

    # Frames arrive as OpenCV's BGR and stay so; the windows cut from them are read as RGB,
    # as the release reads images (imread), which decides fHOG's channel ties and the Color
    # Names index (reference notes, detail 1): fHOG reads BGR windows in RGB order itself, the
    # pixel features convert their windows (``FeatureExtractor(..., bgr=True)``). Converting
    # windows rather than the frame saved 0.4 ms per 1280x720 frame; not converting them at
    # all another 0.1 ms per ARCF-H frame.
    def _frame_for_init(self, frame: np.ndarray) -> tuple[np.ndarray, bool]:
        validate_frame(frame)
        if frame.ndim == 2:
            return frame[..., None], False
        if frame.shape[2] == 1:
            return frame, False
        if np.array_equal(frame[..., 0], frame[..., 1]) and np.array_equal(
            frame[..., 1], frame[..., 2]
        ):
            return frame[..., :1], False  # gray stored as colour: the release drops CN
        return frame, True

    def _frame_for_update(self, frame: np.ndarray) -> np.ndarray:
        validate_frame(frame)
        if frame.shape[:2] != self._image_hw:
            raise InvalidFrameError(
                f"frame size changed from {self._image_hw[1]}x{self._image_hw[0]} to "
                f"{frame.shape[1]}x{frame.shape[0]}; call init() again for a new stream"
            )
        image = frame if frame.ndim == 3 else frame[..., None]
        if self._color and image.shape[2] == 1:
            return np.repeat(image, 3, axis=2)
        if not self._color and image.shape[2] == 3:
            return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)[..., None]
        return image


def validate_frame(frame: Any) -> None:
    """Raise :class:`InvalidFrameError` unless ``frame`` is a uint8 HxW, HxWx1 or HxWx3 array."""
    if not isinstance(frame, np.ndarray):
        raise InvalidFrameError(f"frame must be a numpy array, got {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise InvalidFrameError(f"frame must be uint8 (OpenCV BGR or gray), got {frame.dtype}")
    if frame.ndim not in (2, 3) or (frame.ndim == 3 and frame.shape[2] not in (1, 3)):
        raise InvalidFrameError(
            f"frame must be HxW (gray) or HxWx3 (BGR), got shape {tuple(frame.shape)}"
        )
    if frame.shape[0] < 2 or frame.shape[1] < 2:
        raise InvalidFrameError(f"frame is too small: {frame.shape[1]}x{frame.shape[0]} pixels")


def validate_box(box: Any, image_hw: tuple[int, int]) -> Box:
    """Check an ``(x, y, w, h)`` box against a frame; raise :class:`InvalidBoxError` if absurd.

    A box may stick out of the frame (patches replicate the border), but it must overlap it, be
    at least one pixel in each direction, and not be more than 4x the frame in either direction.
    """
    if isinstance(box, (str, bytes, bytearray)):
        raise InvalidBoxError(f"box must be four numbers (x, y, w, h), got the string {box!r}")
    try:
        values = [float(v) for v in box]
    except (TypeError, ValueError) as exc:
        raise InvalidBoxError(f"box must be four numbers (x, y, w, h), got {box!r}") from exc
    if len(values) != 4:
        raise InvalidBoxError(f"box must be four numbers (x, y, w, h), got {len(values)} values")
    x, y, w, h = values
    if not all(math.isfinite(v) for v in values):
        raise InvalidBoxError(f"box has a NaN or infinite value: {tuple(values)}")
    if w < 1 or h < 1:
        raise InvalidBoxError(f"box must be at least 1x1 pixel, got w={w:g}, h={h:g}")
    ih, iw = image_hw
    if x - 1 >= iw or y - 1 >= ih or x - 1 + w <= 0 or y - 1 + h <= 0:
        raise InvalidBoxError(
            f"box {tuple(values)} lies entirely outside the {iw}x{ih} frame "
            "(boxes use the datasets' 1-based pixel coordinates)"
        )
    if w > 4 * iw or h > 4 * ih:
        raise InvalidBoxError(f"box {tuple(values)} is more than 4x the {iw}x{ih} frame")
    return x, y, w, h


def create_tracker(
    preset: str | TrackerParams = "arcf-hc",
    *,
    colornames_path: str | Path | None = None,
    **overrides: Any,
) -> ARCFTracker:
    """A tracker for a preset (``"arcf-h"``, ``"arcf-hc"``, ``"bacf"``) with keyword overrides.

    >>> tracker = create_tracker("arcf-h", aberrance="release")  # doctest: +SKIP
    """
    return ARCFTracker(make_params(preset, **overrides), colornames_path=colornames_path)

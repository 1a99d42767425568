"""Scale estimation: ARCF-H's joint multi-scale search and ARCF-HC's 1-D DSST scale filter."""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from .features.fhog import Arithmetic as FhogArithmetic
from .features.fhog import fhog
from .features.patches import pyramid_windows, release_windows
from .presets import ScaleFilterParams


def search_scale_factors(n_scales: int, step: float) -> np.ndarray:
    """ARCF-H's scale pyramid: step^e for e = -floor((n-1)/2) .. ceil((n-1)/2) (BACF)."""
    e = np.arange(-((n_scales - 1) // 2), n_scales - (n_scales - 1) // 2)
    return (step**e).astype(np.float64)


def scale_limits(
    step: float,
    sample_px: tuple[float, float],
    base_target_sz: tuple[float, float],
    image_hw: tuple[int, int],
) -> tuple[float, float]:
    """The release's clamp of the scale factor, quantised to powers of ``step``.

    The lower limit keeps the search region at least 5 px; the upper keeps the target inside the
    image. (A target already larger than the image gets max = min, i.e. the scale is frozen.)
    """
    lo_exp = math.ceil(math.log(max(5.0 / sample_px[0], 5.0 / sample_px[1])) / math.log(step))
    hi_arg = min(image_hw[0] / base_target_sz[0], image_hw[1] / base_target_sz[1])
    hi_exp = math.floor(math.log(hi_arg) / math.log(step))
    lo, hi = step**lo_exp, step**hi_exp
    return lo, max(hi, lo)


class DSSTScaleFilter:
    """A 1-D correlation filter over 33 scales of fHOG features (Danelljan et al., DSST).

    Features of each scale are the flattened fHOG (31 channels, cell 4) of the target-sized patch
    resized to a fixed model size, multiplied by a Hann window over the scales; the filter is the
    MOSSE-style ratio sf_num / (sf_den + λ) in the Fourier domain over the scale axis.
    """

    def __init__(
        self,
        params: ScaleFilterParams,
        init_target_sz: tuple[float, float],
        fhog_arithmetic: FhogArithmetic = "release",
        sampling: str = "release",
    ) -> None:
        self.params = params
        self.fhog_arithmetic = fhog_arithmetic
        self.sampling = sampling  # "release" or "pyramid" (TrackerParams.sampling)
        n = params.n_scales
        ss = np.arange(1, n + 1) - math.ceil(n / 2)
        sigma = math.sqrt(n) * params.sigma_factor
        self.ysf = sfft.fft(np.exp(-0.5 * ss.astype(np.float64) ** 2 / sigma**2))
        if n % 2 == 0:
            self.window = np.hanning(n + 1)[1:]
        else:
            self.window = np.hanning(n)
        self.factors = params.scale_step ** (math.ceil(n / 2) - np.arange(1, n + 1))
        area = init_target_sz[0] * init_target_sz[1]
        model_factor = 1.0
        if area > params.model_max_area:
            model_factor = math.sqrt(params.model_max_area / area)
        self.model_sz = (
            max(math.floor(init_target_sz[0] * model_factor), params.model_min_side),
            max(math.floor(init_target_sz[1] * model_factor), params.model_min_side),
        )
        self.sf_num: np.ndarray | None = None
        self.sf_den: np.ndarray | None = None

    def _sample(
        self, image: np.ndarray, pos: tuple[float, float], base_target_sz: tuple[float, float],
        scale: float,
    ) -> np.ndarray:
        """(features, scales) matrix of windowed, flattened fHOG features (DSST's xs)."""
        sizes = [
            # release (DSST): at least 2 px
            (max(math.floor(base_target_sz[0] * f), 2), max(math.floor(base_target_sz[1] * f), 2))
            for f in self.factors * scale
        ]
        if self.sampling == "pyramid":
            patches = pyramid_windows(image, pos, sizes, self.model_sz)
        else:
            patches = release_windows(image, pos, sizes, self.model_sz)
        # frames are BGR, the release's windows RGB: fHOG reads them so
        feats = fhog(patches, 4, arithmetic=self.fhog_arithmetic, bgr=True)  # (S, h, w, 31)
        # column-major (MATLAB's temp(:)) order of each scale's (h, w, 31) block
        xs = feats.transpose(0, 3, 2, 1).reshape(len(patches), -1).T.astype(np.float64)
        return xs * self.window[None, :]

    def estimate(
        self, image: np.ndarray, pos: tuple[float, float], base_target_sz: tuple[float, float],
        scale: float,
    ) -> float:
        """The relative scale change at ``pos`` (one of ``factors``)."""
        assert self.sf_num is not None and self.sf_den is not None
        xsf = sfft.fft(self._sample(image, pos, base_target_sz, scale), axis=1)
        response = np.real(
            sfft.ifft(np.sum(self.sf_num * xsf, axis=0) / (self.sf_den + self.params.regularizer))
        )
        return float(self.factors[int(np.argmax(response))])

    def update(
        self, image: np.ndarray, pos: tuple[float, float], base_target_sz: tuple[float, float],
        scale: float, first: bool,
    ) -> None:
        xsf = sfft.fft(self._sample(image, pos, base_target_sz, scale), axis=1)
        new_num = self.ysf[None, :] * np.conj(xsf)
        new_den = np.sum(np.real(xsf * np.conj(xsf)), axis=0)
        if first or self.sf_num is None or self.sf_den is None:
            self.sf_num, self.sf_den = new_num, new_den
        else:
            lr = self.params.learning_rate
            self.sf_num = (1 - lr) * self.sf_num + lr * new_num
            self.sf_den = (1 - lr) * self.sf_den + lr * new_den

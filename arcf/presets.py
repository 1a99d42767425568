"""Typed, immutable parameter sets of the three trackers of the paper.

Every value says where it comes from: "paper" (Huang et al., ICCV 2019, Section 6.1 / Table 1),
"release" (the authors' public MATLAB code; the details that decide its boxes are in
``docs/release.md``) or "BACF" / "DSST" when the release inherits it unchanged from those
trackers. Where the release departs from the paper, the preset follows the release (that is
what produced the published boxes) and says so.

Overrides are applied with :func:`make_params`, which rejects unknown names so that a typo in an
experiment fails loudly instead of silently running the default.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Literal

from .errors import InvalidParameterError, UnknownPresetError
from .features.fhog import ArithmeticMode as FhogArithmetic
from .state import StateParams

AberranceMode = Literal["paper", "release"]
ScaleMode = Literal["search", "filter"]
SizingMode = Literal["filter_max_area", "sample_area"]
SamplingMode = Literal["release", "pyramid"]
SpectraMode = Literal["release", "half"]
TrainingSampleMode = Literal["extract", "shift"]


@dataclass(frozen=True)
class ScaleFilterParams:
    """The 1-D DSST scale filter of ARCF-HC (release: inherited from DSST)."""

    n_scales: int = 33  # release
    scale_step: float = 1.03  # release (DSST uses 1.02)
    sigma_factor: float = 0.5  # release: label sigma = sqrt(n_scales) * 0.5 = sqrt(33)/2
    learning_rate: float = 0.025  # release / DSST
    regularizer: float = 1e-4  # release / DSST (lambda of the scale filter)
    model_max_area: int = 512  # release / DSST: scale patches resized to at most 512 px (32x16)
    model_min_side: int = 8  # ECO's floor on the scale model size, keeps fHOG >= 2x2 cells

    def __post_init__(self) -> None:
        problems = []
        if not self.n_scales >= 1:
            problems.append("scale_filter.n_scales must be >= 1")
        if not self.scale_step > 1:
            problems.append("scale_filter.scale_step must be > 1")
        if not self.sigma_factor > 0:
            problems.append("scale_filter.sigma_factor must be > 0")
        if not 0 < self.learning_rate <= 1:
            problems.append("scale_filter.learning_rate must be in (0, 1]")
        if not self.regularizer > 0:
            problems.append("scale_filter.regularizer must be > 0")
        if not self.model_max_area >= 16 or not self.model_min_side >= 4:
            problems.append("scale_filter model size too small (max area >= 16, min side >= 4)")
        if problems:
            raise UnknownPresetError("invalid scale filter parameters: " + "; ".join(problems))


@dataclass(frozen=True)
class TrackerParams:
    """Everything that defines one tracker. Field comments give the source of each default."""

    name: str
    #: Feature channels, in block order: "gray" (1), "fhog" (31), "cn" (10, colour frames only).
    features: tuple[str, ...]
    #: ADMM iterations per frame. release ARCF-H: 2 (paper: 5); ARCF-HC: 5.
    admm_iterations: int
    #: Appearance-model learning rate eta. release ARCF-H: 0.019 (paper: 0.0192); ARCF-HC 0.0192.
    learning_rate: float
    #: "search": ARCF-H's joint search over ``n_scales`` scales; "filter": ARCF-HC's DSST filter.
    #: Independent of ``sizing``: either scale strategy works with either family's sizing.
    scale_mode: ScaleMode
    #: Newton iterations of the sub-cell peak search. release: 50 (ARCF-H), 5 (ARCF-HC).
    newton_iterations: int
    #: ARCF-H rounds the translation to whole pixels; ARCF-HC keeps it sub-pixel (release).
    round_translation: bool
    #: How the working resolution is chosen (see :mod:`arcf.tracker`).
    sizing: SizingMode
    #: ARCF-HC's release rounds the boxes it reports to whole pixels; ARCF-H floors the size.
    whole_pixel_boxes: bool = False
    #: gamma, the aberrance penalty (paper and release: 0.71). 0 gives BACF.
    gamma: float = 0.71
    #: lambda, the filter regulariser (paper and release: 0.01).
    admm_lambda: float = 0.01
    #: mu schedule: mu0 = 1, mu <- min(beta mu, mu_max) (release, from BACF).
    mu_init: float = 1.0
    mu_scale_step: float = 10.0
    mu_max: float = 1e4
    #: Aberrance term: "paper" uses the DFT of the shifted previous map (Eq. 5); "release" feeds
    #: the spatial map, T times too strong, into the Fourier-domain formula as the authors' code
    #: does. Each preset sets the one that measured best (see the presets below).
    aberrance: AberranceMode = "paper"
    #: fHOG arithmetic: "release" reproduces the toolbox's SSE approximations (magnitude from an
    #: approximate reciprocal square root, orientation from a 20,000-entry acos table), which
    #: move orientation bins near their boundaries; "exact" bins by exact angle comparisons.
    #: An approximation rather than a choice of the authors, hence an option (docs/release.md,
    #: detail 2).
    fhog_arithmetic: FhogArithmetic = "release"
    #: A CPU's SSE tables (the output of ``tools/sse_approx_dump.c``): the release arithmetic
    #: then replays that CPU's ``RSQRTPS`` / ``RCPPS`` bit for bit instead of modelling the AMD
    #: EPYC that traced the release (None). Their last bits decide orientation bins near
    #: boundaries, and so whether ARCF-H follows a given run of the release. A path on the
    #: host, or a table shipped with the package by name (``"amd-epyc"``, the tracing CPU's,
    #: which ``RELEASE_COMPATIBLE`` replays); a library user's setting, refused in service
    #: requests.
    fhog_sse_table: str | None = None
    #: How windows are cut and shrunk to the working resolution. "release": the release's
    #: sampler, one area resize per window, bit for bit (``mexResize``). "pyramid": windows
    #: more than twice the working size are read from one shared halving pyramid by bilinear
    #: interpolation (``arcf.features.patches.pyramid_windows``), an approximation that is
    #: several times cheaper on large targets (docs/results-speed.md).
    sampling: SamplingMode = "release"
    #: Spectral layout. "release": as the release computes. With ``aberrance="release"`` and
    #: gamma > 0 that means full spectra (its target is a spatial map used as a spectrum, so
    #: its filter is not conjugate symmetric); the other formulations are real and use half
    #: spectra, Newton's peak search then reading the FFT of the spatial response, bit for bit
    #: as before. "half": half spectra everywhere. The release's target is projected onto its
    #: conjugate-symmetric part, (T(n) + conj(T(-n))) / 2, which halves the transforms and ADMM;
    #: the part dropped is the one whose spatial filter is imaginary: the g-, h- and multiplier
    #: steps never mix it into the symmetric part, and Newton's search reads only the real part
    #: of the response's series, so it reaches the release's boxes only through MATLAB's
    #: ``ifft2(.., 'symmetric')`` reading half of a non-symmetric spectrum. Newton's search
    #: reads the correlation's own spectrum, completed by symmetry (the release hands its
    #: ``responsef`` to ``resp_newton``), one transform less. An approximation, measured in
    #: docs/results-speed.md.
    spectra: SpectraMode = "release"
    #: Where each frame's training sample comes from. "extract" (release): a new window cut
    #: at the new position and scale, its features and their DFT. "shift": the detection
    #: features of the chosen scale moved onto the new position, by whole cells in space and
    #: by the remaining fraction of a cell with the DFT's shift theorem (as ECO's
    #: ``shift_sample``, Danelljan et al., CVPR 2017), which saves one window and its fHOG per
    #: frame; an approximation (the wrapped-in border is the opposite border's, the cell grid
    #: is the detection window's). It loses UAV123 truck4_2 in ARCF-H, so no ARCF preset uses
    #: it (the hybrid's verifier does: its box is the network's)
    #: (docs/results-speed.md).
    training_sample: TrainingSampleMode = "extract"
    #: Scale each feature sample to unit mean energy per element, as ECO/STRCF's
    #: ``extract_features`` does (``normalize_power = 2``, ``normalize_size``, ``normalize_dim``).
    #: Off in every preset, as the release does (docs/release.md); measured as an
    #: experiment on ARCF-HC (docs/benchmarks.md), it did not bring the boxes closer overall.
    normalize_features: bool = False
    #: Cell size of all features (release: 4).
    cell_size: int = 4
    #: Search region side = sqrt(w h) * sqrt(search_area_scale) (release: 5, square region).
    search_area_scale: float = 5.0
    #: Gaussian label sigma = sqrt(cells of the target) * output_sigma_factor (release: 1/16).
    output_sigma_factor: float = 1.0 / 16.0
    #: ARCF-H: feature grid at most 2500 cells (50x50) (release, from BACF).
    filter_max_area: int = 2500
    #: ARCF-H: tiny-target rule threshold, 0.75^2 of ``filter_max_area`` (release, from BACF).
    cell_selection_thresh: float = 0.75**2
    #: ARCF-HC: the search region's pixel area is rescaled into [150^2, 200^2], then its side is
    #: rounded to a whole number of cells (release, ECO's ``init_features`` 'exact' size mode).
    min_image_sample_size: float = 150.0**2
    max_image_sample_size: float = 200.0**2
    #: ARCF-H scale search: 5 scales, step 1.01 (release, from BACF).
    n_scales: int = 5
    scale_step: float = 1.01
    #: ARCF-HC scale filter.
    scale_filter: ScaleFilterParams = field(default_factory=ScaleFilterParams)
    #: The track state (tracking / coasting / lost), its confidence model and its update
    #: policy (:mod:`arcf.state`); the default learns every frame, as the release does.
    state: StateParams = field(default_factory=StateParams)

    def __post_init__(self) -> None:
        problems = []
        for name in (
            "learning_rate", "gamma", "admm_lambda", "mu_init", "mu_scale_step", "mu_max",
            "search_area_scale", "output_sigma_factor", "filter_max_area",
            "cell_selection_thresh", "min_image_sample_size", "max_image_sample_size",
            "scale_step",
        ):
            if not math.isfinite(getattr(self, name)):
                problems.append(f"{name} must be a finite number")
        if not self.mu_init > 0 or not self.mu_max >= self.mu_init or not self.mu_scale_step >= 1:
            problems.append("mu schedule needs mu_init > 0, mu_scale_step >= 1, mu_max >= mu_init")
        if not self.search_area_scale >= 1:
            problems.append("search_area_scale must be >= 1")
        if not self.output_sigma_factor > 0:
            problems.append("output_sigma_factor must be > 0")
        if not self.filter_max_area >= 16:
            problems.append("filter_max_area must be >= 16 cells")
        if not self.cell_selection_thresh > 0:
            problems.append("cell_selection_thresh must be > 0")
        if not 0 < self.min_image_sample_size <= self.max_image_sample_size:
            problems.append("need 0 < min_image_sample_size <= max_image_sample_size")
        if not self.scale_step > 1:
            problems.append("scale_step must be > 1")
        if self.newton_iterations < 0:
            problems.append("newton_iterations must be >= 0")
        for name, allowed in (
            ("scale_mode", ("search", "filter")),
            ("fhog_arithmetic", ("exact", "release")),
            ("sizing", ("filter_max_area", "sample_area")),
            ("sampling", ("release", "pyramid")),
            ("spectra", ("release", "half")),
            ("training_sample", ("extract", "shift")),
        ):
            if getattr(self, name) not in allowed:
                problems.append(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        for name in ("admm_iterations", "newton_iterations", "cell_size", "n_scales"):
            if not isinstance(getattr(self, name), int) or isinstance(getattr(self, name), bool):
                problems.append(f"{name} must be an integer, got {getattr(self, name)!r}")
        if self.fhog_sse_table is not None:
            if not isinstance(self.fhog_sse_table, str) or not self.fhog_sse_table:
                problems.append("fhog_sse_table must be a file path, a shipped table's name "
                                "('amd-epyc') or None")
            elif self.fhog_arithmetic != "release":
                problems.append("fhog_sse_table needs fhog_arithmetic='release'")
        for name in ("round_translation", "whole_pixel_boxes", "normalize_features"):
            if not isinstance(getattr(self, name), bool):
                problems.append(f"{name} must be True or False, got {getattr(self, name)!r}")
        if not self.features:
            problems.append("features must name at least one of 'gray', 'fhog', 'cn'")
        if self.admm_iterations < 1:
            problems.append("admm_iterations must be >= 1")
        if not 0.0 < self.learning_rate <= 1.0:
            problems.append("learning_rate must be in (0, 1]")
        if not self.gamma >= 0:
            problems.append("gamma must be >= 0")
        if not self.admm_lambda >= 0:
            problems.append("admm_lambda must be >= 0")
        if self.cell_size < 1:
            problems.append("cell_size must be >= 1")
        if self.n_scales < 1:
            problems.append("n_scales must be >= 1")
        if self.aberrance not in ("paper", "release"):
            problems.append("aberrance must be 'paper' or 'release'")
        unknown = set(self.features) - {"gray", "fhog", "cn"}
        if unknown:
            problems.append(f"unknown features {sorted(unknown)}")
        if problems:
            raise UnknownPresetError(
                f"invalid parameters for {self.name!r}: " + "; ".join(problems)
            )


ARCF_H = TrackerParams(
    name="arcf-h",
    features=("fhog",),
    admm_iterations=2,  # release (paper: 5)
    learning_rate=0.019,  # release (paper: 0.0192)
    scale_mode="search",
    newton_iterations=50,  # release (BACF)
    round_translation=True,  # release (BACF)
    sizing="filter_max_area",
    # Not the release's sampler: measured on the 9 shared sequences (docs/results-speed.md),
    # the pyramid keeps precision / AUC within 0.005 of the exact sampler (arcf-h 0.592 / 0.348
    # against 0.592 / 0.350, bacf 0.508 / 0.310 against 0.513 / 0.311), losing no sequence,
    # and cuts the time per frame on large targets. RELEASE_COMPATIBLE restores the release's.
    sampling="pyramid",
    # Measured best on the 9 shared sequences (docs/results-fidelity.md): the release's form
    # P 0.592 / AUC 0.350, the paper's 0.521 / 0.315 at any γ in 0..1.5 (it loses truck4_2).
    aberrance="release",
    # Not the release's layout: its target's conjugate-symmetric part in half spectra, measured
    # on the 9 shared sequences with the pyramid (docs/results-speed.md): P / AUC
    # 0.598 / 0.358 against the release-compatible 0.592 / 0.350, no sequence lost, 1.2x the
    # frame rate.
    spectra="half",
    # Re-acquisition off (the release learns every frame and never searches): on 21 UAV
    # sequences this project does not have, measured from outside, the whole-frame search
    # jumped onto other things and lowered P@20 / AUC from 0.701 / 0.458 to 0.630 / 0.421
    # (BACF: 0.647 / 0.424 to 0.616 / 0.398), while it found 1 of 6 real losses again. HOG
    # alone does not tell a target from a lookalike well enough to verify a jump (ARCF-HC,
    # whose filter reads colour too, lost nothing there and keeps it). The state and
    # confidence are still reported;
    # ``{"state.reacquire": True}`` turns the search on (docs/track-state.md).
    state=StateParams(reacquire=False),
)

ARCF_HC = TrackerParams(
    name="arcf-hc",
    features=("gray", "fhog", "cn"),
    admm_iterations=5,  # release and paper
    learning_rate=0.0192,  # release and paper
    scale_mode="filter",
    newton_iterations=5,  # release (ECO/STRCF)
    round_translation=False,  # release (ECO/STRCF)
    sizing="sample_area",
    whole_pixel_boxes=True,  # release: reported boxes rounded to whole pixels
    # The release's sampler: with the pyramid, ARCF-HC loses DTB70 BMX3 (precision 0.471 ->
    # 0.074; mean 0.740 / 0.509 -> 0.704 / 0.490, docs/results-speed.md).
    sampling="release",
    # Measured best on the 9 shared sequences (docs/results-fidelity.md): the paper's form
    # P 0.740 / AUC 0.509 (= the authors' published 0.740 / 0.508), the release's 0.699 / 0.494.
    aberrance="paper",
)

#: BACF is ARCF-H without the aberrance term; the release's "Baseline_BACF" was produced this way.
BACF = dataclasses.replace(ARCF_H, name="bacf", gamma=0.0)

PRESETS: dict[str, TrackerParams] = {p.name: p for p in (ARCF_H, ARCF_HC, BACF)}

SiameseNetwork = Literal["nanotrack", "vittrack"]


@dataclass(frozen=True)
class SiameseParams:
    """A Siamese tracker run by OpenCV (``cv2.TrackerNano`` / ``cv2.TrackerVit``) on the
    network files of :mod:`arcf.models`. Its box is the network's; its state is read from the
    network's score against the score of the same track's recent trusted frames, by the same
    state machine as ARCF's (:class:`~arcf.state.TrackMonitor`, the score in place of PSR x
    peak); its confidence is the score itself."""

    name: str
    network: SiameseNetwork
    #: Score below which the tracker reports the target "not located" (VitTrack: OpenCV's
    #: ``TrackerVit_Params.tracking_score_threshold`` default 0.2; NanoTrack has none).
    score_threshold: float = 0.0
    #: The state machine's thresholds (the confidence model's weights are not used).
    state: StateParams = field(default_factory=lambda: StateParams(reacquire=False))


@dataclass(frozen=True)
class HybridParams:
    """ARCF beside a Siamese network (:mod:`arcf.hybrid`): the network gives the box, an ARCF
    filter steered onto that box gives the aberrance, the track state and the confidence, and
    its whole-frame search re-detects a lost target and restarts the network there."""

    name: str
    network: SiameseNetwork
    #: The verifier: an ARCF filter at the network's box and scale, its re-acquisition on.
    verifier: TrackerParams
    #: A re-acquired place restarts the network when it lies farther than this many target
    #: sizes from the network's own box (a choice: a network already on it keeps its template).
    restart_distance: float = 1.0
    #: The agreement that brings a coasting or lost track back where the network is: on
    #: ``agree_frames`` frames in a row, the network's score at least ``agree_score`` of its
    #: recent level, the filter's strength at its box at least ``state.coast_below`` (it sees
    #: something like its target there) and the filter's own peak within ``agree_distance``
    #: target sizes of the network's box. Why: a target that changes its look fast (a
    #: wakeboarder turning) weakens the filter, which then stops learning, while the network,
    #: which never learns, still holds it; a hidden target weakens both (choices, measured in
    #: docs/track-state.md).
    agree_frames: int = 3
    agree_score: float = 0.96
    agree_distance: float = 0.25


NANOTRACK = SiameseParams(name="nanotrack", network="nanotrack")
VITTRACK = SiameseParams(name="vittrack", network="vittrack", score_threshold=0.2)

#: ARCF-H as the hybrid's verifier, everything ARCF-H's but three choices for cost (the box is
#: the network's; the filter only has to tell its target from what is not): one scale (the
#: network measures the target's size), a feature grid of at most 40x40 cells instead of 50x50
#: (32x32 no longer found the person of person12_2 again), and the detection sample shifted
#: onto the new position as the training sample (the window is centred on the network's box, so
#: the shift is the small disagreement between the two; one feature extraction a frame).
#: Its confidence model is its own: the filter's response at another tracker's box reads
#: differently from its response at its own (fitted by ``benchmarks/track_state.py --presets
#: arcf-nano --fit`` on the 9 shared sequences and the 3 occlusion clips; held out sequence by
#: sequence: calibration error 0.013, Brier score 0.011, docs/track-state.md).
ARCF_NANO = HybridParams(
    name="arcf-nano", network="nanotrack",
    verifier=dataclasses.replace(
        ARCF_H, name="arcf-nano.verifier", n_scales=1, filter_max_area=1600,
        training_sample="shift",
        state=StateParams(weights=(1.3058, 2.4204, -0.5922, -3.0288, 0.3066, 0.3689),
                          bias=1.6131)))

#: The overrides that turn a preset into the authors' release, the configuration whose boxes
#: are compared with the release's own runs (docs/results-fidelity.md):
#: ``create_tracker("arcf-h", **RELEASE_COMPATIBLE)``. fHOG replays the SSE instructions of
#: the AMD EPYC that traced the release (a table shipped with the package), so the boxes are
#: the same on any CPU.
RELEASE_COMPATIBLE: Mapping[str, Any] = MappingProxyType(
    {"aberrance": "release", "sampling": "release", "fhog_arithmetic": "release",
     "fhog_sse_table": "amd-epyc", "spectra": "release", "training_sample": "extract",
     # the release learns every frame and never searches: re-acquisition off
     "state.reacquire": False}
)

#: Parameters that name files on the host. A library user sets them; a service must not let a
#: remote request choose which of its files a tracker reads.
HOST_PARAMETERS = frozenset({"fhog_sse_table"})


@dataclass(frozen=True)
class Tunable:
    """An override's declared type and supported range (inclusive bounds, or the allowed
    values). The ranges span every setting of the paper, the release and their ablations with
    room to experiment, and keep one frame's cost bounded (a service accepts no more): a
    research run beyond them builds its :class:`TrackerParams` with ``dataclasses.replace``."""

    kind: type
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None

    def check(self, name: str, value: Any) -> None:
        """Raise :class:`InvalidParameterError` naming the field and what it accepts."""
        want = self.describe()
        if self.kind is bool:
            ok = isinstance(value, bool)
        elif self.kind is int:
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif self.kind is float:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(
                value)
        elif self.kind is tuple:  # a list of choices (the feature channels)
            ok = (isinstance(value, (list, tuple)) and len(value) > 0
                  and all(isinstance(v, str) and v in (self.choices or ()) for v in value)
                  and len(set(value)) == len(value))
        else:
            ok = isinstance(value, str) and value in (self.choices or ())
        if ok and self.low is not None and value < self.low:
            ok = False
        if ok and self.high is not None and value > self.high:
            ok = False
        if not ok:
            raise InvalidParameterError(f"{name} must be {want}, got {value!r}")

    def describe(self) -> str:
        if self.kind is tuple:
            return f"a list of distinct values of {list(self.choices or ())}"
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        name = {bool: "true or false", int: "an integer", float: "a finite number"}[self.kind]
        if self.low is not None and self.high is not None:
            return f"{name} in [{self.low:g}, {self.high:g}]"
        if self.low is not None:
            return f"{name} >= {self.low:g}"
        return name


#: Every parameter a caller may override, with its declared type and range (the table of
#: docs/presets.md, "What an override accepts"). ``name`` is fixed by the preset;
#: ``fhog_sse_table`` is a host path (library only).
TUNABLE: Mapping[str, Tunable] = MappingProxyType({
    "features": Tunable(tuple, choices=("gray", "fhog", "cn")),
    "admm_iterations": Tunable(int, 1, 20),
    "learning_rate": Tunable(float, 1e-4, 1.0),
    "scale_mode": Tunable(str, choices=("search", "filter")),
    "newton_iterations": Tunable(int, 0, 100),
    "round_translation": Tunable(bool),
    "sizing": Tunable(str, choices=("filter_max_area", "sample_area")),
    "whole_pixel_boxes": Tunable(bool),
    "gamma": Tunable(float, 0.0, 100.0),
    "admm_lambda": Tunable(float, 0.0, 100.0),
    "mu_init": Tunable(float, 1e-6, 1e6),
    "mu_scale_step": Tunable(float, 1.0, 1e3),
    "mu_max": Tunable(float, 1e-6, 1e9),
    "aberrance": Tunable(str, choices=("paper", "release")),
    "fhog_arithmetic": Tunable(str, choices=("exact", "release")),
    "sampling": Tunable(str, choices=("release", "pyramid")),
    "spectra": Tunable(str, choices=("release", "half")),
    "training_sample": Tunable(str, choices=("extract", "shift")),
    "normalize_features": Tunable(bool),
    "cell_size": Tunable(int, 1, 8),
    "search_area_scale": Tunable(float, 1.0, 16.0),
    "output_sigma_factor": Tunable(float, 1e-3, 1.0),
    "filter_max_area": Tunable(int, 16, 10_000),
    "cell_selection_thresh": Tunable(float, 1e-3, 1.0),
    "min_image_sample_size": Tunable(float, 16.0, 400.0**2),
    "max_image_sample_size": Tunable(float, 16.0, 400.0**2),
    "n_scales": Tunable(int, 1, 15),
    "scale_step": Tunable(float, 1.0001, 1.5),
    "scale_filter.n_scales": Tunable(int, 1, 65),
    "scale_filter.scale_step": Tunable(float, 1.0001, 1.5),
    "scale_filter.sigma_factor": Tunable(float, 1e-3, 10.0),
    "scale_filter.learning_rate": Tunable(float, 1e-4, 1.0),
    "scale_filter.regularizer": Tunable(float, 1e-8, 1.0),
    "scale_filter.model_max_area": Tunable(int, 16, 4096),
    "scale_filter.model_min_side": Tunable(int, 4, 64),
    # the track state (its logistic weights are checked by StateParams itself: finite)
    "state.bias": Tunable(float, -100.0, 100.0),
    "state.reference_frames": Tunable(int, 1, 300),
    "state.coast_below": Tunable(float, 0.0, 1.0),
    "state.lost_below": Tunable(float, 0.0, 1.0),
    "state.lost_after": Tunable(int, 1, 10_000),
    "state.resume_above": Tunable(float, 0.0, 1.0),
    "state.resume_after": Tunable(int, 0, 10_000),
    "state.update_policy": Tunable(str, choices=("always", "tracking")),
    "state.reacquire": Tunable(bool),
    "state.probes": Tunable(int, 1, 16),
    "state.search_bands": Tunable(int, 1, 64),
    "state.reacquire_above": Tunable(float, 0.0, 1.0),
    "state.reacquire_margin": Tunable(float, 0.0, 1.0),
})


#: The nested parameter groups and their types: overridable as a whole (an instance, or a dict
#: of its fields) or field by field with a dotted name (``"state.reacquire"``), as a service
#: request, ``--set`` and the presets reply spell them.
NESTED_GROUPS: Mapping[str, type] = MappingProxyType(
    {"scale_filter": ScaleFilterParams, "state": StateParams})


def _fold_dotted(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``{"state.reacquire": True}`` -> ``{"state": {"reacquire": True}}``, merged with a dict
    given for the same group; a dotted name outside the nested groups is unknown."""
    out: dict[str, Any] = {}
    dotted: dict[str, dict[str, Any]] = {}
    for key, value in overrides.items():
        group, dot, field_name = key.partition(".")
        if not dot:
            out[key] = value
        elif group in NESTED_GROUPS and field_name and "." not in field_name:
            dotted.setdefault(group, {})[field_name] = value
        else:
            raise UnknownPresetError(
                f"unknown parameter {key!r}; dotted names address the fields of "
                f"{', '.join(NESTED_GROUPS)} (e.g. 'state.reacquire')")
    for group, fields in dotted.items():
        whole = out.get(group)
        if whole is None:
            out[group] = fields
        elif isinstance(whole, dict):
            clash = sorted(set(whole) & set(fields))
            if clash:
                raise InvalidParameterError(
                    f"{group} fields {clash} given twice (as {group}.<name> and in {group})")
            out[group] = {**whole, **fields}
        elif isinstance(whole, NESTED_GROUPS[group]) and dataclasses.is_dataclass(whole):
            out[group] = {**{f.name: getattr(whole, f.name)
                             for f in dataclasses.fields(whole)}, **fields}
        else:
            out[group] = whole  # reported below as a bad group value
    return out


def _nested(base: Any, group: str, value: Any) -> Any:
    """A nested group's override (an instance or a dict of its fields, each field checked
    against ``TUNABLE``) applied to the preset's ``base`` instance."""
    cls = NESTED_GROUPS[group]
    if isinstance(value, cls):
        return value
    if not isinstance(value, dict):
        raise UnknownPresetError(f"{group} must be a {cls.__name__} or a dict of its fields")
    names = {f.name for f in dataclasses.fields(cls)}
    bad = sorted(set(value) - names)
    if bad:
        raise UnknownPresetError(f"unknown {group} parameter(s) {bad}; valid: {sorted(names)}")
    for key, v in value.items():
        tunable = TUNABLE.get(f"{group}.{key}")
        if tunable is not None:
            tunable.check(f"{group}.{key}", v)
    return dataclasses.replace(base, **value)


def preset_key(name: str) -> str:
    """A preset's name as the registry holds it: ``"ARCF_HC"`` and ``"arcf-hc"`` are one."""
    return str(name).lower().replace("_", "-")


def make_params(preset: str | TrackerParams, **overrides: Any) -> TrackerParams:
    """A preset with keyword overrides, e.g. ``make_params("arcf-h", aberrance="release")``.

    The nested groups (``scale_filter``, ``state``) may be overridden whole, with a
    :class:`ScaleFilterParams` / :class:`~arcf.state.StateParams` or a dict of its fields, or
    field by field with dotted names: ``make_params("arcf-hc", **{"state.reacquire": True})``.
    """
    if isinstance(preset, TrackerParams):
        base = preset
    else:
        key = preset_key(preset)
        if key not in PRESETS:
            raise UnknownPresetError(
                f"unknown preset {preset!r}; choose one of {', '.join(sorted(PRESETS))}"
            )
        base = PRESETS[key]
    overrides = _fold_dotted(overrides)
    names = {f.name for f in dataclasses.fields(TrackerParams)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise UnknownPresetError(
            f"unknown parameter(s) {unknown} for preset {base.name!r}; valid: {sorted(names)} "
            f"and the dotted fields of {', '.join(NESTED_GROUPS)}"
        )
    if "name" in overrides:
        raise InvalidParameterError("name is the preset's; choose another preset instead")
    try:
        for key, value in overrides.items():
            if key in TUNABLE:
                TUNABLE[key].check(key, value)
        for group in NESTED_GROUPS:
            if group in overrides:
                overrides[group] = _nested(getattr(base, group), group, overrides[group])
    except InvalidParameterError as exc:
        raise InvalidParameterError(f"invalid parameters for {base.name!r}: {exc}") from None
    if "features" in overrides:
        overrides["features"] = tuple(overrides["features"])
    return dataclasses.replace(base, **overrides) if overrides else base

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
from collections import deque
from dataclasses import dataclass, field
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
from .errors import InvalidFrameError, NotInitializedError, UnknownPresetError
from .features.extract import FeatureExtractor
from .features.fhog import Arithmetic as FhogArithmetic
from .features.patches import matlab_round, pyramid_windows, release_windows
from .features.sse import load_sse_tables
from .fourier import (
    correlate,
    fftshift2d,
    full_spectrum,
    gaussian_label,
    hann2d,
    newton_peak,
    peak_to_sidelobe,
    shift_spectrum,
    spatial_response,
)
from .presets import TrackerParams
from .reacquire import TEMPLATE_EVERY, TEMPLATE_KEEP, TargetTemplate
from .region import Region, RegionFrame, clip_region, contains, cover
from .scale import DSSTScaleFilter, scale_limits, search_scale_factors
from .state import TrackMonitor, TrackState
from .types import Box, TrackResult, validate_box, validate_frame


@dataclass(frozen=True, eq=False)
class Layout:
    """What ``init`` fixes for the whole sequence: the working resolution, the feature grid and
    everything derived from them. Sizes are (rows, cols).

    The tracker works on windows resampled to a *working resolution*; its *scale factor* is the
    number of source pixels per working pixel (the release's ``currentScaleFactor``, ``csf``).
    """

    #: The frame's (rows, cols); every later frame must have it.
    image_hw: tuple[int, int]
    #: Colour frames (Color Names are used) or grey ones.
    color: bool
    #: Side of a feature cell, working pixels (4; smaller for tiny ARCF-H targets).
    cell: int
    #: Side of the square search window, working pixels (the release's ``sz`` / ``img_support_sz``).
    sample_sz: int
    #: (H, W): the feature grid, cells (the release's ``use_sz``).
    grid: tuple[int, int]
    #: The target at scale factor 1, working pixels (the release's ``base_target_sz``).
    target_size: tuple[float, float]
    #: The scale factor at the first frame; results report ``scale`` relative to it.
    initial_scale: float
    #: Working pixels per cell along each axis (``sample_sz / grid``).
    cell_px: tuple[float, float]
    #: σ of the Gaussian label y, cells.
    sigma: float
    #: The window of BACF's cropping matrix B, cells (the release's ``small_filter_sz``).
    filter_size: tuple[int, int]
    #: Main-lobe half-width excluded from the peak-to-sidelobe ratio, cells.
    psr_radius: int
    #: Relative scales searched jointly each frame (ARCF-H: 5 around 1; [1] with DSST).
    scale_factors: np.ndarray
    #: The scale factor's clamp.
    min_scale: float
    max_scale: float
    #: (H, W) float32 cosine window; ŷ, the label's spectrum; B.
    window: np.ndarray
    yf: np.ndarray
    crop: Crop
    extractor: FeatureExtractor


@dataclass(eq=False)
class FrameState:
    """What changes from frame to frame (a failed ``init`` keeps the previous one)."""

    #: Target centre (row, col), in the datasets' 1-based pixel frame.
    pos: tuple[float, float]
    #: Source pixels per working pixel.
    scale_factor: float
    #: x̂ᵐᵒᵈᵉˡ, the running appearance model, (D, H, W') spectra.
    model_xf: np.ndarray
    #: ĝ, the correlation filter, (D, H, W') spectra.
    g_f: np.ndarray
    #: M_{k-1}, the previous response map (fftshifted, peak near the centre), and its peak.
    m_prev: np.ndarray
    p_prev: tuple[int, int]
    frame_index: int
    #: ARCF-HC's DSST scale filter, with its own running model; None with the joint search.
    scale_filter: DSSTScaleFilter | None
    #: ``training_sample="shift"`` only: the chosen scale's detection maps and where the new
    #: position lies in them, cells.
    detection_maps: np.ndarray | None = None
    detection_shift: tuple[float, float] = (0.0, 0.0)
    #: Re-acquisition: the target's grey look at trusted frames, oldest first (the oldest is
    #: what a lost track searches the frame for), and the trusted frames since the last one.
    templates: deque[TargetTemplate] = field(default_factory=lambda: deque(maxlen=TEMPLATE_KEEP))
    trusted_frames: int = 0
    #: The target's grey look at the (re)initialisation, which the confidence compares
    #: every box with.
    initial_look: TargetTemplate | None = None
    #: Position and scale factor on the last tracking frame (the size a lost box keeps).
    tracked: tuple[tuple[float, float], float] | None = None
    #: Where the search saw the target strong on the last lost frame (confirmed on the next).
    candidate: tuple[float, float] | None = None
    #: Places the next lost frame verifies after ``candidate``, best first: one seen
    #: promising off its centre (now centred), then the last band's best.
    leads: list[tuple[float, float]] = field(default_factory=list)
    #: The band of the frame the next lost frame's template search covers.
    search_band: int = 0


@dataclass(frozen=True)
class _Sizing:
    """A sizing rule's answer: where the target is and at which resolution it is worked on."""

    pos: tuple[float, float]
    cell: int
    sample_sz: int
    target_size: tuple[float, float]
    scale_factor: float


def _bacf_sizing(p: TrackerParams, x: float, y: float, w: float, h: float) -> _Sizing:
    """ARCF-H / BACF (``sizing="filter_max_area"``): a square grid of at most
    ``filter_max_area`` cells over ``search_area_scale`` times the target's area (release)."""
    init_sz = np.array([max(math.floor(h), 1), max(math.floor(w), 1)], dtype=np.float64)
    pos = (float(math.floor(y + math.floor(h / 2))), float(math.floor(x + math.floor(w / 2))))
    cell = p.cell_size
    search_area = float(np.prod(init_sz / cell * p.search_area_scale))
    if search_area < p.cell_selection_thresh * p.filter_max_area:
        # tiny targets: a smaller cell keeps enough cells in the grid (release, from BACF)
        need = np.prod(init_sz * p.search_area_scale) / (
            p.cell_selection_thresh * p.filter_max_area
        )
        cell = min(cell, max(1, math.ceil(math.sqrt(need))))
        search_area = float(np.prod(init_sz / cell * p.search_area_scale))
    scale = math.sqrt(search_area / p.filter_max_area) if search_area > p.filter_max_area else 1.0
    base = init_sz / scale
    side = math.sqrt(float(np.prod(base * p.search_area_scale)))
    sz = max(matlab_round(side / cell) * cell, 2 * cell)
    return _Sizing(pos, cell, sz, (float(base[0]), float(base[1])), scale)


def _eco_sizing(p: TrackerParams, x: float, y: float, w: float, h: float) -> _Sizing:
    """ARCF-HC (``sizing="sample_area"``): the search region rescaled to a pixel area in
    [150², 200²] (ECO / STRCF, release)."""
    target = np.array([h, w], dtype=np.float64)
    pos = (y + (h - 1) / 2, x + (w - 1) / 2)
    search_area = float(np.prod(target * p.search_area_scale))
    if search_area > p.max_image_sample_size:
        scale = math.sqrt(search_area / p.max_image_sample_size)
    elif search_area < p.min_image_sample_size:
        scale = math.sqrt(search_area / p.min_image_sample_size)
    else:
        scale = 1.0
    base = target / scale
    cell = p.cell_size
    side = math.sqrt(float(np.prod(base * p.search_area_scale)))
    support = max(matlab_round(side / cell) * cell, 2 * cell)
    return _Sizing(pos, cell, support, (float(base[0]), float(base[1])), scale)


_SIZINGS = {"filter_max_area": _bacf_sizing, "sample_area": _eco_sizing}


#: Pixels added around :meth:`ARCFTracker.read_region`'s windows: the sampling pyramid
#: extends its cut to whole blocks of up to 2^4 pixels.
READ_MARGIN = 16
#: How far the target may move in one frame, as a share of the detection window, for the
#: windows cut after detection to lie in :meth:`ARCFTracker.read_region` (a quarter: about
#: the target's own size for ARCF-H's and BACF's windows of five target sides; further, the
#: update asks for the whole frame).
READ_STEP = 0.25


class ARCFTracker:
    """ARCF-H, ARCF-HC or BACF, depending on its :class:`~arcf.presets.TrackerParams`.

    Two families share the loop: BACF-style sizing with a joint search over a few scales
    (ARCF-H, BACF) and ECO-style sizing with a DSST scale filter (ARCF-HC); ``sizing`` and
    ``scale_mode`` choose each part. ``layout`` holds what ``init`` fixes for the sequence,
    ``state`` what each frame changes.
    """

    def __init__(self, params: TrackerParams, colornames_path: str | Path | None = None, *,
                 models_dir: str | Path | None = None) -> None:
        # models_dir: the registry's common signature (arcf.registry); ARCF reads no network
        self.params = params
        self._colornames_path = str(colornames_path) if colornames_path is not None else None
        self._layout: Layout | None = None
        self._state: FrameState | None = None
        #: the track state's references and state machine (per (re)initialisation)
        self._monitor = TrackMonitor(params.state)
        #: the last frame's strength: PSR x peak over their recent trusted medians (NaN before)
        self.strength = math.nan
        #: during an update on a RegionFrame: the frame, for its whole picture if needed
        self._partial: RegionFrame | None = None
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
        return self._state is not None

    @property
    def layout(self) -> Layout:
        if self._layout is None:
            raise NotInitializedError("call init(frame, box) first")
        return self._layout

    @property
    def state(self) -> FrameState:
        if self._state is None:
            raise NotInitializedError("call init(frame, box) first")
        return self._state

    def init(self, frame: np.ndarray, box: Box | Any) -> TrackResult:
        """Start (or restart) tracking ``box`` in ``frame``; returns the first frame's result.

        A failed (re-)initialisation leaves the tracker exactly as it was, so a bad request on a
        live stream does not break the target already being tracked: the new layout and state
        replace the old ones only once the first frame has been learnt.
        """
        image, color = self._frame_for_init(frame)
        x, y, w, h = validate_box(box, image.shape[:2])
        layout, sizing, scale_filter = self._make_layout(image.shape[:2], color, (x, y, w, h))
        state = FrameState(
            pos=sizing.pos, scale_factor=sizing.scale_factor,
            model_xf=np.empty(0, np.complex64), g_f=np.empty(0, np.complex64),
            m_prev=np.empty((0, 0), np.float32), p_prev=(0, 0), frame_index=0,
            scale_filter=scale_filter,
        )
        # learn the first frame on the new layout and state, then adopt both
        previous = self._layout, self._state
        self._layout, self._state = layout, state
        try:
            state.model_xf = self._training_sample(image)
            state.g_f = self._solve(None)
            first = spatial_response(
                correlate(state.g_f, state.model_xf[None])[0], layout.grid, self._hermitian
            )
            state.m_prev = fftshift2d(first)
            state.p_prev = peak_index(state.m_prev)
            if scale_filter is not None:
                scale_filter.update(image, state.pos, layout.target_size, state.scale_factor,
                                    True)
        except BaseException:
            self._layout, self._state = previous
            raise
        self._monitor.reset()
        state.initial_look = TargetTemplate.cut(image, state.pos, self._size_hw(), search=False)
        if self.params.state.reacquire:
            state.tracked = (state.pos, state.scale_factor)
            state.templates.append(TargetTemplate.cut(image, state.pos, self._size_hw()))
        return TrackResult(
            box=self._box(),
            peak=float(first.max()),
            psr=peak_to_sidelobe(first, layout.psr_radius),
            aberrance=0.0,
            aberrance_release=0.0,
            scale=1.0,
            frame_index=0,
            confidence=1.0,  # the box was given
            state=TrackState.TRACKING,
        )

    def update(self, frame: np.ndarray | RegionFrame) -> TrackResult:
        """Track into the next frame: detect, measure the aberrance, judge the track's state,
        search the frame when lost (re-acquisition on), train (while tracking with
        re-acquisition on; else every frame, or only while tracking:
        ``params.state.update_policy``), and say how confident the box is.

        ``frame`` may be a :class:`~arcf.region.RegionFrame` holding at least
        :meth:`read_region`: the result is the one the whole frame gives (its ``whole()`` is
        asked for when the track goes lost and searches, or when the region falls short)."""
        if self._state is None:
            raise NotInitializedError("call init(frame, box) before update(frame)")
        self._partial = None
        if isinstance(frame, RegionFrame):
            needed = self.read_region()
            if needed is not None and contains(frame.region, needed):
                self._partial, frame = frame, frame.pixels
            else:
                frame = frame.whole()
        try:
            return self._update(self._frame_for_update(frame))
        finally:
            self._partial = None

    def _update(self, image: np.ndarray) -> TrackResult:
        """The update's steps on the frame (``image``: (H, W, C) uint8)."""
        state, layout, policy = self.state, self.layout, self.params.state
        state.frame_index += 1
        was_lost = self._monitor.state is TrackState.LOST
        response, peak, image = self._detect(image)
        frob, spectral, target_f = self._aberrance(response)
        psr = peak_to_sidelobe(response, layout.psr_radius)
        verdict = self._monitor.observe(peak, psr, spectral)
        self.strength = verdict.strength
        state_now, jumped = verdict.state, False
        # what the confidence reads: the frame's response, or the window the track jumped to
        read = (psr, verdict.ln_strength, verdict.ln_aberrance)
        if policy.reacquire and state_now is TrackState.LOST:
            # a lost box keeps the size the target had when last tracked: the scale estimated
            # on what is not the target means nothing
            if state.tracked is not None:
                state.scale_factor = state.tracked[1]
            # the search starts on the frame after the loss: what it reads is then known
            # before the frame arrives (read_region)
            found = None
            if was_lost:
                image = self._reading(image, self._search_region())
                found = self._reacquire(image, verdict.strength)
            if found is not None:
                read, state_now, jumped = found, TrackState.TRACKING, True
                image = self._reading(image, self._look_region())  # at the place jumped to
        # with re-acquisition on, the filter of the last tracking frame is kept while the
        # track is not tracking: it is what still knows the target
        learns = (state_now is TrackState.TRACKING
                  if policy.reacquire or policy.update_policy == "tracking" else True)
        if learns and not jumped:
            self._train(image, target_f)
        if policy.reacquire and state_now is not TrackState.LOST:
            state.candidate, state.leads = None, []
            if state_now is TrackState.TRACKING and not jumped:
                state.tracked = (state.pos, state.scale_factor)
                self._keep_template(image, verdict.strength)
        assert state.initial_look is not None
        look = state.initial_look.similarity(image, state.pos, self._size_hw())
        confidence, _ = self._monitor.confidence(*read, state_now, look, state.frame_index)
        return TrackResult(
            box=self._box(),
            peak=peak,
            psr=psr,
            aberrance=frob,
            aberrance_release=spectral,
            scale=state.scale_factor / layout.initial_scale,
            frame_index=state.frame_index,
            confidence=confidence,
            state=state_now,
            reacquired=was_lost and state_now is TrackState.TRACKING,
        )

    def read_region(self) -> Region | None:
        """The pixels the next :meth:`update` reads, as a :data:`~arcf.region.Region` of the
        frame, or None for the whole frame (before ``init``). While a lost track searches, the
        region also covers the search's band and windows (:meth:`_search_region`).

        A bound, not a trace: the detection windows around the rounded position at the
        largest searched scale, and every window cut after detection (the training sample,
        DSST's samples, the look, the kept template) for a target that moves up to
        :data:`READ_STEP` of the detection window and grows by the largest factor searched
        (the joint search's or DSST's); plus :data:`READ_MARGIN`. A target that moves further
        makes the update ask a :class:`~arcf.region.RegionFrame` for its whole picture
        (``_after_detection``). tests/arcf/test_region.py checks that frames undefined outside
        the region give every preset's results bit for bit."""
        if self._state is None:
            return None
        layout, state = self.layout, self.state
        r, c = self._sample_pos()
        detect = layout.sample_sz * state.scale_factor * float(np.max(layout.scale_factors))
        half = max(detect / 2, READ_STEP * detect + self._after_half()) + READ_MARGIN
        region = clip_region(r - 1 - half, c - 1 - half, r + half, c + half, layout.image_hw)
        if self.params.state.reacquire and self._monitor.state is TrackState.LOST:
            return cover((region, self._search_region()))
        return region

    def _after_half(self) -> float:
        """Half the side of the largest window cut after detection (source pixels), at the
        largest scale the detection can reach from the current one."""
        layout, state = self.layout, self.state
        grow = float(np.max(layout.scale_factors))
        extent = float(layout.sample_sz)  # working pixels
        if state.scale_filter is not None:
            dsst = float(np.max(state.scale_filter.factors))
            grow = max(grow, dsst)
            extent = max(extent, max(layout.target_size) * dsst)
        return extent * min(state.scale_factor * grow, layout.max_scale) / 2

    def _after_detection(self, image: np.ndarray) -> np.ndarray:
        """The frame the rest of the update reads, the target now at its detected place: a
        region frame's whole picture when that place lies beyond what :meth:`read_region`
        allowed for."""
        if self._partial is None:
            return image
        r, c = self.state.pos
        half = self._after_half() + READ_MARGIN
        return self._reading(image, clip_region(r - 1 - half, c - 1 - half, r + half, c + half,
                                                self.layout.image_hw))

    def _reading(self, image: np.ndarray, needed: Region | None) -> np.ndarray:
        """``image``, or the region frame's whole picture when ``needed`` (None: the whole
        frame) lies beyond the region it holds."""
        partial = self._partial
        if partial is None or (needed is not None and contains(partial.region, needed)):
            return image
        self._partial = None
        return self._frame_for_update(partial.whole())

    def _look_region(self) -> Region:
        """The target's box around the current position: what the look reads."""
        (r, c), (h, w) = self.state.pos, self._size_hw()
        return clip_region(r - 2 - h / 2, c - 2 - w / 2, r + 1 + h / 2, c + 1 + w / 2,
                           self.layout.image_hw)

    def steer(self, box: Box) -> None:
        """Search around ``box`` on the next ``update``, at its size: a companion tracker's box
        (the hybrid's network, :mod:`arcf.hybrid`) replaces the filter's own last position.
        A lost track keeps the size of its last tracked frame, as it does on its own."""
        state, layout = self.state, self.layout
        x, y, w, h = (float(v) for v in box)
        if self.params.sizing == "filter_max_area":
            state.pos = (y + math.floor(h / 2), x + math.floor(w / 2))
        else:
            state.pos = (y + (h - 1) / 2, x + (w - 1) / 2)
        if self._monitor.state is not TrackState.LOST and w > 0 and h > 0:
            factor = math.sqrt(w * h / (layout.target_size[0] * layout.target_size[1]))
            state.scale_factor = float(np.clip(factor, layout.min_scale, layout.max_scale))

    def resume(self) -> None:
        """A companion tracker vouches for the box (the hybrid's agreement rule): the track is
        ``tracking`` again from the next frame and learns again, its references taken afresh
        from the frames that follow (the target's look has changed since the old ones)."""
        self._monitor.reset()

    def _keep_template(self, image: np.ndarray, strength: float) -> None:
        """Every ``TEMPLATE_EVERY`` strong tracking frames, the target's look joins the
        kept templates (the oldest is dropped)."""
        state = self.state
        if not strength >= self.params.state.resume_above:
            return
        state.trusted_frames += 1
        if state.trusted_frames >= TEMPLATE_EVERY:
            state.trusted_frames = 0
            state.templates.append(TargetTemplate.cut(image, state.pos, self._size_hw()))

    def _search_places(self) -> list[tuple[float, float]]:
        """The places the next lost frame verifies, in order, at most ``probes``: the one seen
        strong on the frame before (to confirm), the leads (a promising place now centred,
        the last band's best), where the target was last tracked (a target hidden where it
        stood comes back there), the band's others."""
        state = self.state
        first = [state.candidate] if state.candidate is not None else []
        first += state.leads[:1]
        if state.tracked is not None:
            first.append(state.tracked[0])
        return (first + state.leads[1:])[:self.params.state.probes]

    def _search_band(self) -> tuple[int, int]:
        """Source rows ``[top, bottom)`` of the band the next lost frame's template search
        covers (``(0, 0)``: none, no template kept yet)."""
        state = self.state
        if not state.templates:
            return 0, 0
        return state.templates[0].band(self.layout.image_hw, state.search_band,
                                       self.params.state.search_bands)

    def _search_region(self) -> Region | None:
        """What the next lost frame's search reads: the band, whole rows, and a window at
        the track's lost scale around each place it verifies (with the target's box around
        the window's farthest point: the look, should the track jump there)."""
        layout, state = self.layout, self.state
        rows, cols = layout.image_hw
        top, bottom = self._search_band()
        scale = state.tracked[1] if state.tracked is not None else state.scale_factor
        half = (layout.sample_sz * scale + max(layout.target_size) * scale) / 2 + READ_MARGIN
        regions = [clip_region(r - 1 - half, c - 1 - half, r + half, c + half, (rows, cols))
                   for r, c in self._search_places()]
        if bottom > top:
            regions.append((top, 0, bottom, cols))
        return cover(regions) if regions else None

    def _reacquire(self, image: np.ndarray,
                   strength: float) -> tuple[float, float, float] | None:
        """Look for the target (:mod:`arcf.reacquire`), within the frame's budget: the kept
        filter verifies the places queued on the frame before (:meth:`_search_places`), and
        the kept template searches one band of the frame for the next frame's. A place strong
        enough on two frames in a row, and clearly stronger than the box, moves the track
        there; returned are the PSR, ln strength and ln aberrance ratio (0: no previous map
        there) the confidence reads. The box itself keeps following the filter, so a track
        wrongly judged lost loses nothing."""
        state, policy = self.state, self.params.state
        if not state.templates:
            return None
        places, (top, bottom) = self._search_places(), self._search_band()
        best: tuple[float, float, tuple[float, float], np.ndarray] | None = None
        for centre in places:
            peak, psr, pos, response = self._probe(image, centre, state.g_f)
            s = self._monitor.probe(peak, psr)
            if best is None or s > best[0]:
                best = (s, psr, pos, response)
        found = state.templates[0].candidates(image, policy.probes, rows=(top, bottom))
        state.search_band = (state.search_band + 1) % policy.search_bands
        state.leads = [c for _, c in found]
        if math.isnan(strength):
            strength = 0.0
        # the box is abandoned only where it is weaker than a coasting one, for a place
        # clearly stronger than it
        if (best is None or strength >= policy.coast_below or best[0] < policy.reacquire_above
                or best[0] < strength + policy.reacquire_margin):
            state.candidate = None
            if best is not None and best[0] >= policy.lost_below:
                # a promising place may sit off the target's centre, where the cosine
                # window dims it: the next frame's window is centred on the filter's peak
                state.leads.insert(0, best[2])
            return None
        s, psr, pos, response = best
        previous, state.candidate = state.candidate, pos
        reach = max(self._size_hw())
        if previous is None or math.dist(previous, pos) > reach:
            return None  # seen once: confirmed or not on the next frame
        state.pos, state.candidate = pos, None
        state.m_prev = fftshift2d(response)
        state.p_prev = peak_index(state.m_prev)
        self._monitor.resume()
        return psr, math.log(max(s, 1e-6)), 0.0  # (reacquire_above 0 admits strength 0)

    def _probe(
        self, image: np.ndarray, centre: tuple[float, float], g_f: np.ndarray
    ) -> tuple[float, float, tuple[float, float], np.ndarray]:
        """Filter ``g_f``'s response in one window at the track's scale: its peak, PSR, where
        the peak puts the target, and the (H, W) map."""
        p, layout, state = self.params, self.layout, self.state
        centre = (float(matlab_round(centre[0])), float(matlab_round(centre[1])))
        patch = self._patches(image, centre, (1.0,))
        xtf = self._fwd(layout.extractor(patch, layout.color, layout.window, bgr=True))
        rf = correlate(g_f, xtf)
        response = spatial_response(rf[0], layout.grid, self._hermitian)[None]
        disp_r, disp_c, _, peak = newton_peak(response, self._full_spectrum(rf, response),
                                              p.newton_iterations)
        pos = (centre[0] + disp_r * layout.cell_px[0] * state.scale_factor,
               centre[1] + disp_c * layout.cell_px[1] * state.scale_factor)
        return peak, peak_to_sidelobe(response[0], layout.psr_radius), pos, response[0]

    # ------------------------------------------------------------------ configuration
    def _make_layout(
        self, image_hw: tuple[int, int], color: bool, box: Box
    ) -> tuple[Layout, _Sizing, DSSTScaleFilter | None]:
        """The sequence's layout from the first box, by the preset's sizing and scale rules."""
        p = self.params
        x, y, w, h = box
        sizing = _SIZINGS[p.sizing](p, x, y, w, h)
        cell, sz = sizing.cell, sizing.sample_sz
        grid = (sz // cell, sz // cell)
        cells = np.floor(np.asarray(sizing.target_size) / cell)
        sigma = math.sqrt(max(float(np.prod(cells)), 1.0)) * p.output_sigma_factor
        filter_size = (int(np.clip(cells[0], 1, grid[0])), int(np.clip(cells[1], 1, grid[1])))
        scale_filter: DSSTScaleFilter | None = None
        if p.scale_mode == "search":  # joint search over n_scales scales (ARCF-H, BACF)
            factors, step = search_scale_factors(p.n_scales, p.scale_step), p.scale_step
        else:  # DSST's separate 1-D scale filter (ARCF-HC)
            factors, step = np.ones(1), p.scale_filter.scale_step
            scale_filter = DSSTScaleFilter(
                p.scale_filter, (float(h), float(w)), self._fhog_arithmetic, p.sampling
            )
        min_scale, max_scale = scale_limits(step, (sz, sz), sizing.target_size, image_hw)
        extractor = FeatureExtractor(
            p.features, cell, self._colornames_path, p.normalize_features,
            self._fhog_arithmetic,
        )
        extractor.prepare(color)
        layout = Layout(
            image_hw=image_hw,
            color=color,
            cell=cell,
            sample_sz=sz,
            grid=grid,
            target_size=sizing.target_size,
            initial_scale=sizing.scale_factor,
            cell_px=(sz / grid[0], sz / grid[1]),
            sigma=sigma,
            filter_size=filter_size,
            psr_radius=max(2, math.ceil(3 * sigma)),
            scale_factors=factors,
            min_scale=min_scale,
            max_scale=max_scale,
            window=hann2d(grid),
            yf=self._fwd(gaussian_label(grid, sigma)),
            crop=Crop(grid, filter_size),
            extractor=extractor,
        )
        return layout, sizing, scale_filter

    # ------------------------------------------------------------------ the three steps
    def _detect(self, image: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """Step 1: locate the target; updates position and scale. Returns (map, peak value,
        the frame the rest of the update reads: ``_after_detection``)."""
        p, layout, state = self.params, self.layout, self.state
        sample_pos = self._sample_pos()
        patches = self._patches(image, sample_pos, layout.scale_factors)
        if p.training_sample == "shift":
            maps = layout.extractor(patches, layout.color, bgr=True)  # unwindowed, for training
            xtf = self._fwd(maps * layout.window)  # (S, D, H, W')
        else:
            xtf = self._fwd(layout.extractor(patches, layout.color, layout.window, bgr=True))
        rf = correlate(state.g_f, xtf)  # (S, H, W')
        if rf.shape[0] == 1:
            response = spatial_response(rf[0], layout.grid, self._hermitian)[None]
        else:
            response = spatial_response(rf, layout.grid, self._hermitian)
        disp_r, disp_c, sind, peak = newton_peak(response, self._full_spectrum(rf, response),
                                                 p.newton_iterations)

        factor = float(layout.scale_factors[sind])
        px_per_cell = (layout.cell_px[0] * state.scale_factor * factor,
                       layout.cell_px[1] * state.scale_factor * factor)
        step_r = disp_r * px_per_cell[0]
        step_c = disp_c * px_per_cell[1]
        if p.round_translation:
            step_r, step_c = float(matlab_round(step_r)), float(matlab_round(step_c))
        state.pos = (sample_pos[0] + step_r, sample_pos[1] + step_c)
        if p.training_sample == "shift":
            # what "shift" training reuses: this sample, and where the new position lies in it
            state.detection_maps = maps[sind]
            new_pos = self._sample_pos()
            state.detection_shift = (
                (new_pos[0] - sample_pos[0]) / px_per_cell[0],
                (new_pos[1] - sample_pos[1]) / px_per_cell[1],
            )
        image = self._after_detection(image)
        if state.scale_filter is not None:
            factor = state.scale_filter.estimate(image, state.pos, layout.target_size,
                                                 state.scale_factor)
        state.scale_factor = float(np.clip(state.scale_factor * factor, layout.min_scale,
                                           layout.max_scale))
        return response[sind], peak, image

    def _full_spectrum(self, rf: np.ndarray, response: np.ndarray) -> np.ndarray:
        """The responses' full spectra, (S, H, W), as Newton's peak refinement reads them."""
        if not self._hermitian:
            return rf
        if self.params.spectra == "half":  # what the release's Newton reads: the correlation's
            return full_spectrum(rf, self.layout.grid[1], np.complex128)  # Newton's precision
        return sfft.fft2(response)  # bit for bit the earlier formulation (release BACF)

    def _aberrance(
        self, response: np.ndarray
    ) -> tuple[float, float, np.ndarray | None]:
        """Step 2: map difference (Eq. 2) and the aberrance target of the next ADMM solve."""
        state = self.state
        m_curr = fftshift2d(response)
        p_curr = peak_index(m_curr)
        m_prev_shifted = shift_to(state.m_prev, state.p_prev, p_curr)
        frob, spectral = map_difference(m_prev_shifted, m_curr)
        target_f: np.ndarray | None = None
        if self.params.gamma:
            if self.params.aberrance == "paper":
                target_f = self._fwd(
                    paper_target(state.m_prev, state.p_prev).astype(np.float32))
            elif self._hermitian:
                target_f = symmetric_half(release_target(m_prev_shifted)).astype(np.complex64)
            else:
                target_f = release_target(m_prev_shifted).astype(np.complex64)
        state.m_prev, state.p_prev = m_curr, p_curr
        return frob, spectral, target_f

    def _train(self, image: np.ndarray, target_f: np.ndarray | None) -> None:
        """Step 3: the new sample into the running model, the filter from it, the scale
        filter's model."""
        p, state = self.params, self.state
        if p.training_sample == "shift":
            sample = self._shifted_sample()
        else:
            sample = self._training_sample(image)
        # x̂ <- (1 - η) x̂ + η x̂_t, in place: the same products and sum, no new model array
        sample *= p.learning_rate
        state.model_xf *= 1 - p.learning_rate
        state.model_xf += sample
        state.g_f = self._solve(target_f)
        if state.scale_filter is not None:
            state.scale_filter.update(image, state.pos, self.layout.target_size,
                                      state.scale_factor, False)

    def _training_sample(self, image: np.ndarray) -> np.ndarray:
        """Step 3a: windowed features at the new position and scale, in the Fourier domain."""
        layout = self.layout
        patch = self._patches(image, self._sample_pos(), (1.0,))
        return self._fwd(layout.extractor(patch, layout.color, layout.window, bgr=True)[0])

    def _shifted_sample(self) -> np.ndarray:
        """Step 3a with ``training_sample="shift"``: the detection sample of the chosen scale
        moved onto the new position, by whole cells in space (so that the cosine window stays
        centred) and by the remaining fraction of a cell in the Fourier domain."""
        state, layout = self.state, self.layout
        assert state.detection_maps is not None
        dr, dc = state.detection_shift
        whole = (int(np.round(dr)), int(np.round(dc)))
        maps = np.roll(state.detection_maps, (-whole[0], -whole[1]), axis=(-2, -1))
        xf = self._fwd(maps * layout.window)
        return shift_spectrum(xf, (dr - whole[0], dc - whole[1]), layout.grid)

    def _solve(self, target_f: np.ndarray | None) -> np.ndarray:
        """Step 3b: the filter ĝ from the running model by ADMM."""
        p, layout = self.params, self.layout
        g_f, _ = solve_filter(
            self.state.model_xf,
            layout.yf,
            target_f,
            gamma=p.gamma,
            admm_lambda=p.admm_lambda,
            iterations=p.admm_iterations,
            crop=layout.crop,
            hermitian=self._hermitian,
            mu_init=p.mu_init,
            mu_scale_step=p.mu_scale_step,
            mu_max=p.mu_max,
        )
        return g_f

    # ------------------------------------------------------------------ helpers
    def _sample_pos(self) -> tuple[float, float]:
        """Where windows are cut: the position rounded to a pixel (ARCF-H's already is)."""
        pos = self.state.pos
        return float(matlab_round(pos[0])), float(matlab_round(pos[1]))

    def _patches(
        self, image: np.ndarray, pos: tuple[float, float], factors: Any
    ) -> np.ndarray:
        """The search windows at relative scales ``factors``, resized to the working size.

        (N, S, S, C) uint8 in the frame's BGR order (the feature extractor reads them as the
        release's RGB), S = ``layout.sample_sz``; each window's side is ``round(S * scale
        factor * factor)`` source pixels (release: ``get_pixels``).
        """
        sz, scale = self.layout.sample_sz, self.state.scale_factor
        sides = [matlab_round(sz * scale * f) for f in factors]
        out_hw = (sz, sz)
        if self.params.sampling == "pyramid":
            return pyramid_windows(image, pos, [(s, s) for s in sides], out_hw)
        return release_windows(image, pos, [(s, s) for s in sides], out_hw)

    def _fwd(self, maps: np.ndarray) -> np.ndarray:
        return sfft.rfft2(maps) if self._hermitian else sfft.fft2(maps)

    def _size_hw(self) -> tuple[float, float]:
        """The target's current size, source pixels (rows, cols)."""
        layout, state = self.layout, self.state
        return (layout.target_size[0] * state.scale_factor,
                layout.target_size[1] * state.scale_factor)

    def _box(self) -> Box:
        state = self.state
        th, tw = self._size_hw()
        r, c = state.pos
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
    # Names index (docs/release.md, detail 1): fHOG reads BGR windows in RGB order itself, the
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
        layout = self.layout
        if frame.shape[:2] != layout.image_hw:
            raise InvalidFrameError(
                f"frame size changed from {layout.image_hw[1]}x{layout.image_hw[0]} to "
                f"{frame.shape[1]}x{frame.shape[0]}; call init() again for a new stream"
            )
        image = frame if frame.ndim == 3 else frame[..., None]
        if layout.color and image.shape[2] == 1:
            return np.repeat(image, 3, axis=2)
        if not layout.color and image.shape[2] == 3:
            return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)[..., None]
        return image

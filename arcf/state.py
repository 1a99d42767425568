"""Track state: does the tracker still see its target?

A correlation filter always returns a box, target or not. What tells a failure is the shape of
its response: a sharp, tall peak while the filter sees what it learnt, a low, flat one when it
does not. Per frame the tracker reports three signals (:class:`arcf.tracker.TrackResult`):

* ``psr``, the peak-to-sidelobe ratio of the response map (scale-free);
* ``peak``, the response maximum, whose scale depends on the target and the filter's
  regularisation, so it is read against the same track's own start;
* ``aberrance_release``, the map difference of Eq. 2 as the release measures it, read the same
  way.

:class:`TrackMonitor` turns them into causal features (ln PSR, and the logarithms of the peak
and the aberrance relative to their medians over the first frames after (re)initialisation),
then into a **confidence**: a logistic model of the probability that the box overlaps the
target at all (IoU > 0), fitted on real sequences by ``benchmarks/track_state.py`` (the fit and
its data are recorded with the preset values). A small state machine with hysteresis makes the
per-frame confidence a **state**:

* ``tracking``: the confidence is at or above ``coast_below`` (or came back above
  ``resume_above``);
* ``coasting``: it fell below ``coast_below``: the target is probably hidden or blurred, the box
  is the filter's best guess;
* ``lost``: it fell below ``lost_below``, or stayed below ``coast_below`` for ``lost_after``
  frames.

With ``update_policy="tracking"`` the tracker learns only while ``tracking`` (no appearance
update from an occluder or the background); ``"always"`` is the paper's and the release's
behaviour, and the default of the presets, so their boxes stay the release's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Literal

from .errors import InvalidParameterError

UpdatePolicy = Literal["always", "tracking"]

#: keeps the logarithms finite on a flat map (PSR 0) or a zero aberrance (the first frames)
_EPS = 1e-6


class TrackState(str, Enum):
    TRACKING = "tracking"
    COASTING = "coasting"
    LOST = "lost"


#: the states as numbers, for numeric files (the runner's ``_details.csv``)
STATE_CODES = {TrackState.TRACKING: 0, TrackState.COASTING: 1, TrackState.LOST: 2}

#: feature names, in the order of ``StateParams.weights``
FEATURES = ("ln_psr", "ln_peak_ratio", "ln_aberrance_ratio")


@dataclass(frozen=True)
class StateParams:
    """The confidence model and the state machine's thresholds (see the module docstring)."""

    #: Logistic weights of ``FEATURES`` and the bias. Calibration: ``benchmarks/track_state.py``
    #: 2026-11-26, fitted on our runs of ARCF-HC, ARCF-H and BACF on the 9 shared sequences
    #: (4,701 frames, 1,005 of them failures); its scores in docs/benchmarks.md §11.
    weights: tuple[float, float, float] = (1.4402, 1.3118, 0.7472)
    bias: float = -2.5754
    #: Frames after (re)initialisation whose median peak and aberrance are the references.
    reference_frames: int = 10
    #: Confidence below which the state leaves ``tracking`` (coasting). Read off the same
    #: calibration's curve (2026-11-26): the point that flags most failure episodes early
    #: (recall 0.73 within 3 frames) at 160 false alarms per 1,000 good frames, far from the
    #: goal of 2 (docs/benchmarks.md §11).
    coast_below: float = 0.5
    #: Confidence below which the target is lost at once (same curve: 24 false alarms per
    #: 1,000 good frames below 0.2).
    lost_below: float = 0.2
    #: Frames of coasting after which the target counts as lost (1 s at 10 fps; a choice).
    lost_after: int = 10
    #: Confidence from which a coasting or lost track is tracking again (hysteresis; a choice
    #: one step above ``coast_below``).
    resume_above: float = 0.6
    #: "always" learns every frame (paper, release); "tracking" only while tracking.
    update_policy: UpdatePolicy = "always"
    #: Re-acquisition (:mod:`arcf.reacquire`): while lost, keep the last trusted model (no
    #: learning, whatever the policy) and probe more windows around where the target was last
    #: tracked. Off in the presets, so that their boxes stay the paper's.
    reacquire: bool = False
    #: Extra single-scale windows probed per lost frame: the bound on a lost frame's cost
    #: (measured in docs/benchmarks.md §12).
    probes: int = 2
    #: Growth of the searched disc per lost frame, in search windows (from one window at the
    #: loss; a choice: a 4-window disc after 12 frames).
    search_growth: float = 0.25
    #: A probe moves the box only if its confidence is at least ``resume_above`` and beats the
    #: box's own by this much: jumping away is riskier than resuming in place. A choice made on
    #: the shared sequences (2026-11-26, ``benchmarks/reacquire.py``): the wrong jumps seen
    #: without it (onto a similar animal, a rider's background) won by 0.06 to 0.2.
    reacquire_margin: float = 0.3

    def __post_init__(self) -> None:
        problems = []
        if len(self.weights) != len(FEATURES) or not all(map(math.isfinite, self.weights)):
            problems.append(f"state.weights must be {len(FEATURES)} finite numbers")
        if not math.isfinite(self.bias):
            problems.append("state.bias must be finite")
        if self.reference_frames < 1 or self.lost_after < 1:
            problems.append("state.reference_frames and state.lost_after must be >= 1")
        if not 0 <= self.lost_below <= self.coast_below <= self.resume_above <= 1:
            problems.append("state thresholds must satisfy 0 <= lost_below <= coast_below "
                            "<= resume_above <= 1")
        if self.probes < 1 or not (math.isfinite(self.search_growth)
                                   and self.search_growth >= 0):
            problems.append("state.probes must be >= 1 and state.search_growth >= 0")
        if not 0 <= self.reacquire_margin <= 1:
            problems.append("state.reacquire_margin must be in [0, 1]")
        if self.update_policy not in ("always", "tracking"):
            problems.append("state.update_policy must be 'always' or 'tracking'")
        if problems:
            raise InvalidParameterError("invalid track-state parameters: " + "; ".join(problems))


@dataclass(frozen=True)
class Assessment:
    """The monitor's verdict on one frame."""

    state: TrackState
    #: Estimated probability that the box overlaps the target (IoU > 0), in [0, 1].
    confidence: float
    #: The features it was computed from, in ``FEATURES`` order.
    features: tuple[float, float, float]


def _median(values: list[float]) -> float:
    s = sorted(values)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


@dataclass
class TrackMonitor:
    """Per-track state: the references of the current (re)initialisation and the state
    machine. :meth:`reset` on every ``init``; :meth:`observe` on every ``update``."""

    params: StateParams
    state: TrackState = TrackState.TRACKING
    coasting_for: int = 0
    _peaks: list[float] = field(default_factory=list)
    _aberrances: list[float] = field(default_factory=list)

    def reset(self) -> Assessment:
        """A new box was given: the track starts ``tracking`` with full confidence, and the
        next frames set the references."""
        self.state, self.coasting_for = TrackState.TRACKING, 0
        self._peaks, self._aberrances = [], []
        return Assessment(TrackState.TRACKING, 1.0, (0.0, 0.0, 0.0))

    def features(self, peak: float, psr: float, aberrance: float) -> tuple[float, float, float]:
        """The causal features of one frame; the first ``reference_frames`` frames also set
        the references (so they read 0 against a reference made of themselves)."""
        if len(self._peaks) < self.params.reference_frames:
            self._peaks.append(peak)
            self._aberrances.append(aberrance)
        ref_peak, ref_ab = _median(self._peaks), _median(self._aberrances)
        return (math.log(max(psr, 0.0) + _EPS),
                math.log((max(peak, 0.0) + _EPS) / (max(ref_peak, 0.0) + _EPS)),
                math.log((max(aberrance, 0.0) + _EPS) / (max(ref_ab, 0.0) + _EPS)))

    def confidence(self, features: tuple[float, float, float]) -> float:
        z = self.params.bias + sum(w * f for w, f in zip(self.params.weights, features,
                                                         strict=True))
        return 1.0 / (1.0 + math.exp(-z)) if z > -700 else 0.0

    def step(self, confidence: float) -> TrackState:
        """The state machine's move on one frame's confidence (hysteresis: leaving
        ``tracking`` takes less than coming back)."""
        p = self.params
        if self.state is TrackState.TRACKING:
            if confidence < p.lost_below:
                self.state = TrackState.LOST
            elif confidence < p.coast_below:
                self.state, self.coasting_for = TrackState.COASTING, 1
        elif confidence >= p.resume_above:
            self.state, self.coasting_for = TrackState.TRACKING, 0
        elif self.state is TrackState.COASTING:
            self.coasting_for += 1
            if confidence < p.lost_below or self.coasting_for >= p.lost_after:
                self.state = TrackState.LOST
        return self.state

    def probe_confidence(self, peak: float, psr: float) -> float:
        """The confidence of a window probed away from the box (re-acquisition): its PSR and
        peak against the track's references; its aberrance, which compares a map with the
        previous frame's at the box, has no meaning there and reads as the reference's."""
        f = (math.log(max(psr, 0.0) + _EPS),
             math.log((max(peak, 0.0) + _EPS) / (max(_median(self._peaks), 0.0) + _EPS)), 0.0)
        return self.confidence(f) if all(map(math.isfinite, f)) else 0.0

    def resume(self) -> None:
        """The target was found again away from the box: back to ``tracking``."""
        self.state, self.coasting_for = TrackState.TRACKING, 0

    def observe(self, peak: float, psr: float, aberrance: float) -> Assessment:
        """One frame's signals: its features, confidence and the state they lead to (a NaN
        signal gives confidence 0: nothing can be trusted)."""
        f = self.features(peak, psr, aberrance)
        c = self.confidence(f) if all(map(math.isfinite, f)) else 0.0
        return Assessment(self.step(c), c, f)

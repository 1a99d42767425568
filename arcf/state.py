"""Track state: does the tracker still see its target?

A correlation filter always returns a box, target or not. What tells a failure is the shape of
its response: a sharp, tall peak while the filter sees what it learnt, a low, flat one when it
does not. Per frame the tracker reports three signals (:class:`arcf.types.TrackResult`):

* ``psr``, the peak-to-sidelobe ratio of the response map;
* ``peak``, the response maximum;
* ``aberrance_release``, the map difference of Eq. 2 as the release measures it.

What they are worth depends on the target: a small boat on glittering water gives a PSR that a
car on a road would only give when hidden. So :class:`TrackMonitor` reads each frame against
the same track's **recent trusted frames** (the medians over the last ``reference_frames``
frames judged ``tracking``): a real loss is a sudden drop of PSR and peak from their recent
level, which a hard but well-followed target does not show. Its features are ln PSR and the
logarithms of the PSR, the peak and the aberrance relative to those medians. A logistic model
of them gives the **confidence**, the probability that the box overlaps the target at all
(IoU > 0), fitted on real sequences by ``benchmarks/track_state.py``. A small state machine with
hysteresis makes the per-frame confidence a **state**:

* ``tracking``: the confidence is at or above ``coast_below`` (or came back above
  ``resume_above``); only these frames feed the references;
* ``coasting``: it fell below ``coast_below``: the target is probably hidden or blurred, the box
  is the filter's best guess;
* ``lost``: it fell below ``lost_below``, or stayed below ``coast_below`` for ``lost_after``
  frames.

A coasting or lost track is ``tracking`` again where its box is when its strength comes back
above ``resume_above``, or stays at or above ``coast_below`` for ``resume_after`` frames in a
row: a filter that learns nothing while not tracking follows a target whose look changes with
a response that never regains its old level, steady where a hidden or lost target's drops.

With ``update_policy="tracking"`` the tracker learns only while ``tracking`` (no appearance
update from an occluder or the background); ``"always"`` is the paper's and the release's
behaviour. With ``reacquire`` on, nothing is learnt while the track is not ``tracking``
whatever the policy: the filter kept is the one that still knows the target
(:mod:`arcf.reacquire`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
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
FEATURES = ("ln_psr", "ln_strength", "ln_aberrance_ratio", "not_tracking", "look",
            "ln_frames")

#: frames of a (re)initialisation that always feed the references, whatever their state: the
#: references need a few values before a drop can be measured against them
MIN_REFERENCES = 3


@dataclass(frozen=True)
class StateParams:
    """The confidence model and the state machine's thresholds (see the module docstring)."""

    #: Logistic weights of ``FEATURES`` and the bias: the confidence model shared by ARCF's
    #: presets, fitted by ``benchmarks/track_state.py --fit --features
    #: ln_psr,not_tracking,ln_frames`` on the presets as shipped, on the 9 shared sequences and
    #: the 3 occlusion clips (docs/track-state.md). Three features, not six: held out sequence
    #: by sequence, they score best by the Brier score (0.092-0.190 per preset against
    #: 0.099-0.202) and flag hidden frames (mean confidence 0.30-0.44); ln PSR and the frames
    #: alone were better calibrated on average but stayed at 0.5-0.7 on hidden frames.
    weights: tuple[float, float, float, float, float, float] = (
        3.4171, 0.0, 0.0, -1.7360, 0.0, -1.6770)
    bias: float = 1.5189
    #: Recent trusted frames whose median PSR, peak and aberrance are the references (2 s at
    #: 10 fps; a choice: long enough to ride over one bad frame, short enough to follow a
    #: target whose look changes).
    reference_frames: int = 20
    #: Strength (PSR x peak over their recent medians) below which the state leaves
    #: ``tracking`` (coasting): a third of the recent level, about the 0.5 % quantile of the
    #: strength of well-tracked frames (IoU > 0.5) of the three presets on the shared
    #: sequences, which every real occlusion onset of the clips falls below
    #: (docs/track-state.md).
    coast_below: float = 0.33
    #: Strength below which the target is lost at once (a choice: an eighth).
    lost_below: float = 0.12
    #: Frames of coasting after which the target counts as lost (a choice: 0.5 s at 10 fps).
    lost_after: int = 5
    #: Strength from which a coasting or lost track is tracking again where its box is
    #: (hysteresis; a choice).
    resume_above: float = 0.6
    #: Frames in a row at or above ``coast_below`` after which a coasting or lost track is
    #: tracking again where its box is (0: only ``resume_above`` resumes).
    resume_after: int = 0
    #: Strength a place found by the search needs, on two frames in a row, for the box to
    #: jump there (re-acquisition; a choice: as for resuming in place. 0.4 and 0.45 found no
    #: more targets on the occlusion clips, docs/track-state.md).
    reacquire_above: float = 0.6
    #: "always" learns every frame (paper, release); "tracking" only while tracking.
    update_policy: UpdatePolicy = "always"
    #: Re-acquisition (:mod:`arcf.reacquire`): while not tracking, keep the last trusted model
    #: (no learning, whatever the policy); once lost, look for the target over the whole frame.
    reacquire: bool = True
    #: Windows verified per lost frame with the trusted filter (:mod:`arcf.reacquire`): with
    #: ``search_bands``, the bound on a lost frame's cost. Four, a choice: the place to
    #: confirm (or a promising one, centred), the band's best, where the target was last
    #: tracked, the band's second; three found one target fewer again on the made losses
    #: (docs/track-state.md).
    probes: int = 4
    #: Bands the frame's template search is split into, one band per lost frame, so that the
    #: whole frame is searched every ``search_bands`` frames (a choice: 4, a quarter of a
    #: whole-frame search per frame).
    search_bands: int = 4
    #: A place moves the box only if its strength also beats the box's own by this much, and
    #: the box is weaker than a coasting frame: jumping away is riskier than resuming in
    #: place (a choice: a 0.1 margin jumped onto BMX3's background, docs/track-state.md).
    reacquire_margin: float = 0.3

    def __post_init__(self) -> None:
        problems = []
        if len(self.weights) != len(FEATURES) or not all(map(math.isfinite, self.weights)):
            problems.append(f"state.weights must be {len(FEATURES)} finite numbers")
        if not math.isfinite(self.bias):
            problems.append("state.bias must be finite")
        if self.reference_frames < 1 or self.lost_after < 1:
            problems.append("state.reference_frames and state.lost_after must be >= 1")
        if self.resume_after < 0:
            problems.append("state.resume_after must be >= 0")
        if not 0 <= self.lost_below <= self.coast_below <= self.resume_above <= 1:
            problems.append("state thresholds must satisfy 0 <= lost_below <= coast_below "
                            "<= resume_above <= 1")
        if self.probes < 1 or self.search_bands < 1:
            problems.append("state.probes and state.search_bands must be >= 1")
        if not 0 <= self.reacquire_above <= 1:
            problems.append("state.reacquire_above must be in [0, 1]")
        if not 0 <= self.reacquire_margin <= 1:
            problems.append("state.reacquire_margin must be in [0, 1]")
        if self.update_policy not in ("always", "tracking"):
            problems.append("state.update_policy must be 'always' or 'tracking'")
        if problems:
            raise InvalidParameterError("invalid track-state parameters: " + "; ".join(problems))


Features = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class Assessment:
    """The monitor's reading of one frame's response."""

    state: TrackState
    #: PSR x peak over their medians on the recent trusted frames (1: as usual; NaN: unknown).
    strength: float
    #: ln of the strength, and of the aberrance over its recent median.
    ln_strength: float
    ln_aberrance: float


def _median(values: Iterable[float]) -> float:
    s = sorted(values)
    n = len(s)
    if n == 0:
        return math.nan
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def _log_ratio(value: float, reference: float) -> float:
    return math.log((max(value, 0.0) + _EPS) / (max(reference, 0.0) + _EPS))


@dataclass
class TrackMonitor:
    """Per-track state: the recent references and the state machine. :meth:`reset` on every
    ``init``; :meth:`observe` on every ``update``."""

    params: StateParams
    state: TrackState = TrackState.TRACKING
    coasting_for: int = 0
    #: frames in a row, while not tracking, at or above ``coast_below``
    seen_for: int = 0
    #: (psr, peak, aberrance) of the recent trusted frames, oldest first
    _refs: deque[tuple[float, float, float]] = field(default_factory=deque)
    _since_reset: int = 0
    _medians: tuple[float, float, float] | None = None

    def reset(self) -> Assessment:
        """A new box was given: the track starts ``tracking``, and the next frames set the
        references."""
        self.state, self.coasting_for, self.seen_for = TrackState.TRACKING, 0, 0
        self._refs = deque(maxlen=self.params.reference_frames)
        self._medians = None
        self._since_reset = 0
        return Assessment(TrackState.TRACKING, 1.0, 0.0, 0.0)

    def references(self) -> tuple[float, float, float]:
        """The median PSR, peak and aberrance of the recent trusted frames (NaN before any);
        computed once per new reference."""
        if self._medians is None:
            self._medians = (_median(r[0] for r in self._refs),
                             _median(r[1] for r in self._refs),
                             _median(r[2] for r in self._refs))
        return self._medians

    def ln_strength(self, peak: float, psr: float) -> float:
        """ln of PSR x peak over their recent medians (0 before any reference: a frame is
        its own reference)."""
        if not self._refs:
            return 0.0 if math.isfinite(peak) and math.isfinite(psr) else math.nan
        ref_psr, ref_peak, _ = self.references()
        return _log_ratio(psr, ref_psr) + _log_ratio(peak, ref_peak)

    def confidence(self, psr: float, ln_strength: float, ln_aberrance: float,
                   state: TrackState, look: float, frames: int) -> tuple[float, Features]:
        """The calibrated probability that the box overlaps the target, and its features.

        ``look`` is the box's grey look against the target's at the (re)initialisation
        (normalised cross-correlation, :meth:`arcf.reacquire.TargetTemplate.similarity`), and
        ``frames`` the frames since it: a track that has run long has had more chances to
        drift, which no single frame's response shows.
        """
        f = (math.log(max(psr, 0.0) + _EPS), ln_strength, ln_aberrance,
             0.0 if state is TrackState.TRACKING else 1.0, look, math.log1p(max(frames, 0)))
        if not all(map(math.isfinite, f)):
            return 0.0, f
        z = self.params.bias + sum(w * v for w, v in zip(self.params.weights, f, strict=True))
        return (1.0 / (1.0 + math.exp(-z)) if z > -700 else 0.0), f

    def step(self, strength: float) -> TrackState:
        """The state machine's move on one frame's strength (hysteresis: leaving
        ``tracking`` takes less than coming back; NaN counts as nothing seen)."""
        p = self.params
        if not math.isfinite(strength):
            strength = 0.0
        if self.state is TrackState.TRACKING:
            if strength < p.lost_below:
                self.state = TrackState.LOST
            elif strength < p.coast_below:
                self.state, self.coasting_for = TrackState.COASTING, 1
            return self.state
        self.seen_for = self.seen_for + 1 if strength >= p.coast_below else 0
        if strength >= p.resume_above or 0 < p.resume_after <= self.seen_for:
            self.resume()
        elif self.state is TrackState.COASTING:
            self.coasting_for += 1
            if strength < p.lost_below or self.coasting_for >= p.lost_after:
                self.state = TrackState.LOST
        return self.state

    def probe(self, peak: float, psr: float) -> float:
        """The strength of a window probed away from the box (re-acquisition), against the
        references (0 before any)."""
        ln_s = self.ln_strength(peak, psr) if self._refs else math.nan
        return math.exp(ln_s) if math.isfinite(ln_s) else 0.0

    def resume(self) -> None:
        """The target is seen again (where the box is, or found away from it): back to
        ``tracking``."""
        self.state, self.coasting_for, self.seen_for = TrackState.TRACKING, 0, 0

    def observe(self, peak: float, psr: float, aberrance: float) -> Assessment:
        """One frame's signals: its strength and the state it leads to. A frame that stays
        ``tracking`` (and the first few after a reset) becomes one of the references."""
        ln_s = self.ln_strength(peak, psr)
        if self._refs:
            ln_ab = _log_ratio(aberrance, self.references()[2])
        else:
            ln_ab = 0.0 if math.isfinite(aberrance) else math.nan
        strength = math.exp(ln_s) if math.isfinite(ln_s) else math.nan
        state = self.step(strength)
        self._since_reset += 1
        finite = all(map(math.isfinite, (peak, psr, aberrance)))
        if finite and (state is TrackState.TRACKING or self._since_reset <= MIN_REFERENCES):
            self._refs.append((psr, peak, aberrance))
            self._medians = None
        return Assessment(state, strength, ln_s, ln_ab)

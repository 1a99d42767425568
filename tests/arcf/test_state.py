"""The track state: strength against the track's recent trusted frames, the confidence, the
state machine with its hysteresis, and the update policies that stop learning from a lost
target."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import arcf
from arcf.errors import InvalidParameterError
from arcf.presets import make_params
from arcf.state import StateParams, TrackMonitor, TrackState


def test_parameters_are_checked() -> None:
    with pytest.raises(InvalidParameterError, match="thresholds"):
        StateParams(coast_below=0.1, lost_below=0.3)
    with pytest.raises(InvalidParameterError, match="weights"):
        StateParams(weights=(1.0, 2.0))  # type: ignore[arg-type]
    with pytest.raises(InvalidParameterError, match="update_policy"):
        StateParams(update_policy="sometimes")  # type: ignore[arg-type]
    assert make_params("arcf-h", state={"update_policy": "tracking"}).state.update_policy == \
        "tracking"
    assert make_params("arcf-h", **{"state.lost_after": 7}).state.lost_after == 7
    with pytest.raises(arcf.UnknownPresetError, match="unknown state parameter"):
        make_params("arcf-h", state={"threshold": 1})


def test_strength_reads_psr_and_peak_against_the_recent_trusted_frames() -> None:
    monitor = TrackMonitor(StateParams(reference_frames=4))
    assert monitor.reset().state is TrackState.TRACKING
    for psr, peak in ((8.0, 0.02), (10.0, 0.03), (9.0, 0.025)):  # the first frames: references
        monitor.observe(peak=peak, psr=psr, aberrance=0.01)
    assert monitor.references()[:2] == pytest.approx((9.0, 0.025))
    # a frame at half the usual PSR and peak: a quarter of the strength, coasting
    verdict = monitor.observe(peak=0.0125, psr=4.5, aberrance=0.01)
    assert verdict.strength == pytest.approx(0.25, rel=1e-3)
    assert verdict.state is TrackState.COASTING
    assert monitor.references()[:2] == pytest.approx((9.0, 0.025))  # not a reference
    # a strong frame again: tracking, and one of the references, which keep the newest only
    for _ in range(4):
        assert monitor.observe(peak=0.04, psr=12.0, aberrance=0.01).state is \
            TrackState.TRACKING
    assert monitor.references()[:2] == pytest.approx((12.0, 0.04))
    monitor.reset()  # a new box: new references
    assert monitor.observe(peak=0.001, psr=2.0, aberrance=0.04).strength == pytest.approx(1.0)


def test_the_state_machine_coasts_loses_and_resumes_with_hysteresis() -> None:
    params = StateParams(coast_below=0.5, lost_below=0.2, lost_after=3, resume_above=0.7)
    m = TrackMonitor(params)
    m.reset()
    states = [m.step(c).value for c in (0.9, 0.4, 0.45, 0.6, 0.4, 0.8, 0.1, 0.65, 0.75)]
    assert states == ["tracking", "coasting", "coasting",  # 0.6: below resume, still coasting
                      "lost",  # coasting for lost_after frames
                      "lost", "tracking",  # back only at resume_above
                      "lost",  # below lost_below: lost at once
                      "lost", "tracking"]
    m.reset()
    nothing = m.observe(peak=math.nan, psr=5.0, aberrance=0.0)
    assert nothing.state is TrackState.LOST
    assert m.confidence(5.0, nothing.ln_strength, nothing.ln_aberrance, nothing.state, 0.5,
                        3)[0] == 0.0


def test_a_steady_weak_response_resumes_after_resume_after_frames() -> None:
    """A target seen steadily at or above ``coast_below`` (a filter that learnt nothing
    while not tracking, on a target whose look changed) is tracking again after
    ``resume_after`` frames in a row, from coasting or lost; a frame below breaks the run."""
    params = StateParams(coast_below=0.5, lost_below=0.2, lost_after=2, resume_above=0.7,
                         resume_after=3)
    m = TrackMonitor(params)
    m.reset()
    strengths = (0.4, 0.55, 0.55, 0.6,  # coasting, lost (lost_after), the third steady: back
                 0.4, 0.1, 0.6, 0.45, 0.6, 0.6, 0.6)  # lost at once; a run broken, then whole
    assert [m.step(s).value for s in strengths] == [
        "coasting", "lost", "lost", "tracking",
        "coasting", "lost", "lost", "lost", "lost", "lost", "tracking"]
    off = TrackMonitor(dataclasses.replace(params, resume_after=0))
    off.reset()
    assert [off.step(s).value for s in (0.4, 0.6, 0.6, 0.6, 0.6, 0.6, 0.6)][-1] == "lost"


def test_the_confidence_is_the_fitted_model_of_the_features() -> None:
    params = StateParams(weights=(1.0, 2.0, -0.5, -1.5, 0.8, -0.3), bias=-2.0)
    m = TrackMonitor(params)
    m.reset()
    c, f = m.confidence(psr=math.e, ln_strength=0.5, ln_aberrance=0.2,
                        state=TrackState.COASTING, look=0.6, frames=9)
    assert f == pytest.approx((1.0, 0.5, 0.2, 1.0, 0.6, math.log(10)), abs=1e-5)
    z = 1.0 + 2.0 * 0.5 - 0.5 * 0.2 - 1.5 + 0.8 * 0.6 - 0.3 * math.log(10) - 2.0
    assert c == pytest.approx(1 / (1 + math.exp(-z)), rel=1e-5)
    # the shipped model (ln PSR, the state and the track's age): a sharp response is trusted,
    # a flat one is not, and an old or a coasting track less than a young tracking one
    shipped = TrackMonitor(StateParams())
    sharp = shipped.confidence(12.0, 0.0, 0.0, TrackState.TRACKING, 0.8, 10)[0]
    flat = shipped.confidence(3.0, 0.0, 0.0, TrackState.TRACKING, 0.8, 50)[0]
    older = shipped.confidence(12.0, 0.0, 0.0, TrackState.TRACKING, 0.8, 200)[0]
    coasting = shipped.confidence(12.0, 0.0, 0.0, TrackState.COASTING, 0.8, 10)[0]
    assert sharp > 0.9 and flat < 0.3 and older < sharp and coasting < sharp


def _frames(n: int = 6) -> tuple[list[np.ndarray], tuple[float, float, float, float]]:
    """A textured square drifting over noise: something a tracker can follow."""
    rng = np.random.default_rng(3)
    patch = rng.integers(0, 255, (40, 40, 3), dtype=np.uint8)
    frames = []
    for k in range(n):
        img = rng.integers(90, 110, (240, 320, 3), dtype=np.uint8)
        img[100:140, 100 + 2 * k:140 + 2 * k] = patch
        frames.append(img)
    return frames, (101.0, 101.0, 40.0, 40.0)


@pytest.mark.parametrize(("policy", "reacquire"),
                         [("always", False), ("tracking", False), ("always", True)])
def test_only_a_tracking_target_is_learnt_when_asked(policy: str, reacquire: bool) -> None:
    tracker = arcf.create_tracker("bacf", state={"update_policy": policy,
                                                 "reacquire": reacquire})
    frames, box = _frames()
    first = tracker.init(frames[0], box)
    assert (first.state, first.confidence) == (TrackState.TRACKING, 1.0)
    assert tracker.update(frames[1]).state is TrackState.TRACKING
    learnt = tracker.state.g_f.copy()

    def never(strength: float) -> TrackState:  # a monitor that trusts nothing any more
        tracker._monitor.state = TrackState.LOST
        return TrackState.LOST

    tracker._monitor.step = never  # type: ignore[method-assign]
    for frame in frames[2:]:
        r = tracker.update(frame)
        assert r.state is TrackState.LOST
    unchanged = np.array_equal(tracker.state.g_f, learnt)
    assert unchanged == (policy == "tracking" or reacquire)


def test_a_target_that_vanishes_is_coasted_then_lost() -> None:
    tracker = arcf.create_tracker("bacf")
    frames, box = _frames(16)
    tracker.init(frames[0], box)
    seen = [tracker.update(f) for f in frames[1:6]]
    assert all(r.state is TrackState.TRACKING for r in seen)
    rng = np.random.default_rng(5)  # then only noise: the target is gone
    gone = [tracker.update(rng.integers(90, 110, frames[0].shape, dtype=np.uint8))
            for _ in range(10)]
    assert gone[0].state is not TrackState.TRACKING  # at once
    lost_after = tracker.params.state.lost_after
    assert all(r.state is TrackState.LOST for r in gone[lost_after:])
    assert max(r.confidence for r in gone) < min(r.confidence for r in seen)

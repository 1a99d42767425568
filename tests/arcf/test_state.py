"""The track state: features against the track's own start, the confidence, the state machine
with its hysteresis, and the update policy that stops learning from a lost target."""

from __future__ import annotations

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
    with pytest.raises(arcf.UnknownPresetError, match="unknown state parameter"):
        make_params("arcf-h", state={"threshold": 1})


def test_features_read_peak_and_aberrance_against_the_tracks_start() -> None:
    monitor = TrackMonitor(StateParams(reference_frames=3))
    assert monitor.reset().state is TrackState.TRACKING
    for _ in range(3):  # the references: median of the first three frames
        f = monitor.features(peak=0.02, psr=8.0, aberrance=0.01)
        assert f == pytest.approx((math.log(8.0), 0.0, 0.0), abs=1e-4)
    f = monitor.features(peak=0.005, psr=8.0, aberrance=0.04)  # not a reference any more
    assert f[1] == pytest.approx(math.log(0.25), abs=1e-3)
    assert f[2] == pytest.approx(math.log(4.0), abs=1e-3)
    monitor.reset()  # a new box: new references
    assert monitor.features(peak=0.005, psr=8.0, aberrance=0.04)[1:] == pytest.approx((0, 0))


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
    assert m.observe(peak=math.nan, psr=5.0, aberrance=0.0).confidence == 0.0


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


@pytest.mark.parametrize("policy", ["always", "tracking"])
def test_only_a_tracking_target_is_learnt_when_asked(policy: str) -> None:
    # a confidence model that never trusts anything: every update is lost
    never = {"weights": (0.0, 0.0, 0.0), "bias": -50.0, "update_policy": policy}
    tracker = arcf.create_tracker("bacf", state=never)
    frames, box = _frames()
    first = tracker.init(frames[0], box)
    assert (first.state, first.confidence) == (TrackState.TRACKING, 1.0)
    learnt = tracker.state.g_f.copy()
    for frame in frames[1:]:
        r = tracker.update(frame)
        assert r.state is TrackState.LOST and r.confidence < 1e-9
    unchanged = np.array_equal(tracker.state.g_f, learnt)
    assert unchanged == (policy == "tracking")


def test_a_target_that_vanishes_is_coasted_then_lost() -> None:
    tracker = arcf.create_tracker("bacf")
    frames, box = _frames(16)
    tracker.init(frames[0], box)
    seen = [tracker.update(f) for f in frames[1:6]]
    assert all(r.state is TrackState.TRACKING for r in seen)
    rng = np.random.default_rng(5)  # then only noise: the target is gone
    gone = [tracker.update(rng.integers(90, 110, frames[0].shape, dtype=np.uint8))
            for _ in range(10)]
    assert gone[0].state is TrackState.COASTING  # at once
    assert gone[-1].state is TrackState.LOST  # within lost_after (10) frames
    assert max(r.confidence for r in gone) < min(r.confidence for r in seen)

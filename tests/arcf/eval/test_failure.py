"""Failure-detection scores on hand-made sequences whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest

from arcf.eval.failure import episodes, failure_frames, pool, pr_curve, score_flags


def test_failure_is_no_overlap_or_no_target_and_good_is_iou_above_half() -> None:
    gt = np.array([[10, 10, 20, 20], [10, 10, 20, 20], [10, 10, 20, 20], [np.nan] * 4,
                   [0, 0, 0, 0]], dtype=float)
    pred = np.array([[10, 10, 20, 20],   # IoU 1: good
                     [20, 10, 20, 20],   # IoU ~1/3: neither
                     [100, 100, 20, 20],  # IoU 0: failure
                     [10, 10, 20, 20],   # no target: failure whatever the box
                     [10, 10, 20, 20]], dtype=float)  # degenerate annotation: no target
    failure, good = failure_frames(pred, gt)
    assert failure.tolist() == [False, False, True, True, True]
    assert good.tolist() == [True, False, False, False, False]


def test_episodes_are_maximal_runs() -> None:
    assert episodes(np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)) == [(1, 3), (4, 5), (7, 8)]
    assert episodes(np.zeros(4, bool)) == []


def test_a_flag_within_the_delay_catches_the_frames_before_it() -> None:
    failure = np.zeros(20, bool)
    failure[5:15] = True  # one episode of 10 frames
    good = ~failure
    flags = np.zeros(20, bool)
    flags[8:15] = True  # up 3 frames after the onset, until the end
    s = score_flags(flags, failure, good, delay=3)
    assert s.caught == 10 and s.recall_at == 1.0  # frames 5..7 are within 3 of the flag
    assert s.delays == (3,) and s.missed_episodes == 0 and s.episodes == 1
    late = np.zeros(20, bool)
    late[9:15] = True  # 4 frames late: frame 5 is not caught
    s = score_flags(late, failure, good, delay=3)
    assert s.caught == 9 and s.delays == (4,)
    # a flag after the episode ended catches nothing of it, and is a false alarm
    after = np.zeros(20, bool)
    after[15:17] = True
    s = score_flags(after, failure, good, delay=3)
    assert s.caught == 0 and s.missed_episodes == 1 and s.false_alarms == 2
    assert s.false_alarms_per_1000 == pytest.approx(2000 / 10)
    assert s.precision == 0.0


def test_pooling_weighs_every_frame_and_the_curve_runs_from_all_to_nothing() -> None:
    rng = np.random.default_rng(0)
    failure = {k: rng.random(200) < 0.2 for k in "ab"}
    good = {k: ~failure[k] for k in "ab"}
    # a score that separates perfectly: every failure frame above 0.5, every other below
    score = {k: np.where(failure[k], 0.8, 0.2) + rng.random(200) * 0.1 for k in "ab"}
    a, b = (score_flags(score[k] >= 0.5, failure[k], good[k]) for k in "ab")
    pooled = pool([a, b])
    assert pooled.failure_frames == a.failure_frames + b.failure_frames
    assert pooled.recall_at == 1.0 and pooled.precision == 1.0
    assert pooled.false_alarms_per_1000 == 0.0
    curve = pr_curve(score, failure, good, thresholds=[0.0, 0.5, 2.0])
    assert curve[0].recall_at == 1.0 and curve[0].false_alarms_per_1000 == 1000.0
    assert curve[1].precision == 1.0
    assert curve[2].recall_at == 0.0 and np.isnan(curve[2].precision)


def test_shapes_must_agree() -> None:
    with pytest.raises(ValueError, match="differ in shape"):
        score_flags(np.zeros(3, bool), np.zeros(4, bool), np.zeros(4, bool))


def _folder(tmp_path, with_state: bool = True):
    """A run's folder by hand: 10 frames, the box off the target on frames 5..9 (a failure
    episode), flagged from frame 6 (one frame late), and the ground truth."""
    from arcf.eval.results import write_results

    res, gt = tmp_path / "run", tmp_path / "gt"
    truth = np.tile([10.0, 10.0, 20.0, 20.0], (10, 1))
    boxes = truth.copy()
    boxes[5:] = [200.0, 200.0, 20.0, 20.0]
    write_results(res / "s.txt", boxes)
    write_results(gt / "s.txt", truth)
    state = np.zeros(10)
    state[6:] = 2
    conf = np.where(state > 0, 0.1, 0.9)
    cols = "peak,psr,aberrance,aberrance_release,scale"
    rows = np.column_stack([np.ones((10, 5)), conf, state]) if with_state else np.ones((10, 5))
    header = cols + (",confidence,state" if with_state else "")
    np.savetxt(res / "s_details.csv", rows, delimiter=",", header=header, comments="")
    return res, gt


def test_a_run_folder_is_scored_from_its_states(tmp_path, capsys) -> None:
    from arcf.cli import main
    from arcf.eval.failure import score_folder_failures

    res, gt = _folder(tmp_path)
    (s,) = score_folder_failures(res, gt).values()
    assert (s.score.failure_frames, s.score.caught, s.score.delays) == (5, 5, (1,))
    assert s.score.false_alarms == 0
    assert main(["eval", "failure", str(res), str(gt), "--plot", str(tmp_path / "c.png")]) == 0
    out = capsys.readouterr().out
    assert "| s | 5 | 1.000 | 1.000 | 0.0 | 1/1 | 1 |" in out
    assert "| 0.5 | 1.000 | 1.000 | 0.0 |" in out  # the confidence alone, below 0.5
    assert (tmp_path / "c.png").stat().st_size > 1000


def test_a_run_without_states_is_refused_with_the_reason(tmp_path) -> None:
    from arcf.eval.failure import score_folder_failures
    from arcf.eval.results import ResultsError

    res, gt = _folder(tmp_path, with_state=False)
    with pytest.raises(ResultsError, match="no state column"):
        score_folder_failures(res, gt)

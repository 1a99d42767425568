"""Target presence (arcf.eval.presence): precision, recall and F-score of the frames a run
reports ``tracking``, counted by hand on small runs."""

from __future__ import annotations

import numpy as np
import pytest

from arcf.eval.presence import pool, score_presence


def _run():
    """11 frames (frame 0: the given box), the target hidden on frames 4..6; the box on the
    target (IoU 1) on 1..3, half off it (IoU 1/3) on 7..8, elsewhere on 9..10."""
    gt = np.tile([10.0, 10.0, 20.0, 20.0], (11, 1))
    gt[4:7] = np.nan
    boxes = np.tile([10.0, 10.0, 20.0, 20.0], (11, 1))
    boxes[7:9] = [20.0, 10.0, 20.0, 20.0]  # shifted by half its width: IoU 10*20 / (600) = 1/3
    boxes[9:] = [300.0, 300.0, 20.0, 20.0]
    return boxes, gt


def test_a_frame_is_right_when_reported_and_on_the_visible_target() -> None:
    boxes, gt = _run()
    # tracking on 1..3 (right), on 4 (hidden: wrong), on 7 (right), on 9 (off target: wrong)
    reported = np.zeros(11, bool)
    reported[[0, 1, 2, 3, 4, 7, 9]] = True
    s = score_presence(boxes, gt, reported)
    assert (s.frames, s.visible, s.reported, s.right) == (10, 7, 6, 4)
    assert s.precision == pytest.approx(4 / 6)
    assert s.recall == pytest.approx(4 / 7)
    assert s.f_score == pytest.approx(2 * (4 / 6) * (4 / 7) / (4 / 6 + 4 / 7))
    # VOT-LT: IoU summed over the reported frames: 3 x 1 + 0 + 1/3 + 0
    assert s.overlap == pytest.approx(3 + 1 / 3)
    assert s.tracking_precision == pytest.approx((3 + 1 / 3) / 6)
    assert s.tracking_recall == pytest.approx((3 + 1 / 3) / 7)


def test_a_tracker_that_never_says_lost_loses_precision_not_recall() -> None:
    boxes, gt = _run()
    always = score_presence(boxes, gt, np.ones(11, bool))
    honest = np.ones(11, bool)
    honest[4:7] = False  # lost while hidden
    honest[9:] = False  # and once it is elsewhere
    told = score_presence(boxes, gt, honest)
    assert told.recall == always.recall == pytest.approx(5 / 7)
    assert told.precision == 1.0 and always.precision == pytest.approx(5 / 10)
    assert told.f_score > always.f_score


def test_nothing_reported_scores_zero_and_pooling_adds_frames() -> None:
    boxes, gt = _run()
    none = score_presence(boxes, gt, np.zeros(11, bool))
    assert np.isnan(none.precision) and none.recall == 0.0 and none.f_score == 0.0
    some = score_presence(boxes, gt, np.ones(11, bool))
    both = pool([none, some])
    assert (both.frames, both.visible, both.reported, both.right) == (20, 14, 10, 5)
    assert both.recall == pytest.approx(5 / 14)
    with pytest.raises(ValueError):
        score_presence(boxes, gt, np.ones(5, bool))


def test_arcf_eval_presence_reads_a_run_folder(tmp_path, capsys) -> None:
    from arcf.cli import main
    from arcf.eval.results import write_results

    boxes, gt = _run()
    res, gtdir = tmp_path / "run", tmp_path / "gt"
    write_results(res / "s.txt", boxes)
    write_results(gtdir / "s.txt", gt)
    state = np.zeros(11)
    state[4:7] = 2
    state[9:] = 1
    rows = np.column_stack([np.ones((11, 5)), np.full(11, 0.5), state])
    np.savetxt(res / "s_details.csv", rows, delimiter=",", comments="",
               header="peak,psr,aberrance,aberrance_release,scale,confidence,state")
    assert main(["eval", "presence", str(res), str(gtdir)]) == 0
    out = capsys.readouterr().out
    # reported 1..3 and 7..8: 5 frames, all right; visible 7
    assert "| s | 10 | 7 | 5 | 1.000 / 0.714 / 0.833 |" in out
    with pytest.raises(SystemExit, match="not found"):
        main(["eval", "presence", str(tmp_path / "nothing"), str(gtdir), "--sequences", "s"])

"""A whole sequence, timed and scored: ARCF-H on DTB70 MountainBike6 against its ground truth."""

import cv2

import arcf
from arcf.eval import load_dataset, score_sequence

seq = load_dataset("dtb70", sequences=["MountainBike6"])[0]  # frame paths and ground truth
frames = (cv2.imread(str(p)) for p in seq.frames)

arcf.warm_up()
tracker = arcf.create_tracker("arcf-h", **{"state.lost_after": 10})  # any override
run = arcf.run_sequence(tracker, frames, tuple(seq.groundtruth[0]))
score = score_sequence(run.boxes, seq.groundtruth)  # the toolkit's convention
print(f"{seq.name}: {len(run.results)} frames at {run.fps:.0f} FPS, "
      f"P@20 {score.precision20:.3f}, AUC {score.auc:.3f}")

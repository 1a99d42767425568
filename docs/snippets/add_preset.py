"""A candidate preset tried before it is added: ARCF-H searching 3 scales instead of 5, next
to ARCF-H on the same frames of UAV123@10fps wakeboard10."""

import dataclasses

import cv2

import arcf
from arcf.eval import load_dataset, score_sequence
from arcf.presets import ARCF_H
from arcf.registry import create_tracker, family_of
from arcf.run import run_sequence

# a preset is one frozen parameter set of a family, with its own name
ARCF_H_3S = dataclasses.replace(ARCF_H, name="arcf-h-3s", n_scales=3)
print("family:", family_of(ARCF_H_3S).name)  # "arcf": TrackerParams -> ARCFTracker

seq = load_dataset("uav123_10fps", sequences=["wakeboard10"])[0]
frames = [cv2.imread(str(p)) for p in seq.frames[:80]]
truth = seq.groundtruth[:80]
arcf.warm_up()  # the compiled kernels, before anything is timed
for preset in ("arcf-h", ARCF_H_3S):  # a name, or the parameters themselves
    run = run_sequence(create_tracker(preset), frames, tuple(truth[0]))
    score = score_sequence(run.boxes, truth)
    name = preset if isinstance(preset, str) else preset.name
    print(f"{name}: P@20 {score.precision20:.3f}, AUC {score.auc:.3f}, {run.fps:.0f} FPS")

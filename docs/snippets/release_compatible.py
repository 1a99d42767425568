"""ARCF-H as the authors' release runs it, next to the release's own boxes on truck4_1."""

import cv2
import numpy as np

import arcf
from arcf.data import data_root
from arcf.eval import load_dataset

seq = load_dataset("uav123_10fps", sequences=["truck4_1"])[0]
release = np.loadtxt(data_root() / "reference_release/boxes/ARCF-H/truck4_1.txt", delimiter=",")

# the release's aberrance form, sampler, spectra, fHOG arithmetic and the tracing AMD EPYC's
# RSQRTPS / RCPPS tables ("amd-epyc"; or the path of a table dumped on another CPU)
tracker = arcf.create_tracker("arcf-h", **arcf.RELEASE_COMPATIBLE)
frames = (cv2.imread(str(p)) for p in seq.frames[:60])
run = arcf.run_sequence(tracker, frames, tuple(seq.groundtruth[0]))

def centre(b: np.ndarray) -> np.ndarray:
    return b[:, :2] + b[:, 2:] / 2

gap = np.linalg.norm(centre(run.boxes) - centre(release[:60]), axis=1)
print(f"{len(gap)} frames, mean centre distance to the release: {gap.mean():.2f} px")

"""Track the boat of UAV123@10fps boat1 through its first 30 frames with ARCF-HC."""

import cv2

import arcf
from arcf.data import data_root  # $ARCF_DATA, else ../shared/data beside the checkout

frames = sorted((data_root() / "uav123_10fps/data_seq/boat1").glob("*.jpg"))[:30]

arcf.warm_up()  # once per process: loads the compiled kernels
tracker = arcf.create_tracker("arcf-hc")  # or "arcf-nano", "arcf-h", "nanotrack", ...
first = cv2.imread(str(frames[0]))  # uint8 BGR (or H x W gray)
tracker.init(first, (393, 328, 155, 319))  # x, y, w, h in the datasets' 1-based pixels
for path in frames[1:]:
    r = tracker.update(cv2.imread(str(path)))
    print(r.frame_index, r.box, r.state.value, f"{r.confidence:.2f}", f"{r.aberrance:.4f}")

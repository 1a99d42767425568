"""A session through a running arcf-service: 20 frames of boat1 sent, every result printed."""

import os

import cv2

from arcf.client import TrackingClient
from arcf.data import data_root

endpoint = os.environ.get("ARCF_ENDPOINT", "tcp/127.0.0.1:7447")  # arcf-service's default
frames = sorted((data_root() / "uav123_10fps/data_seq/boat1").glob("*.jpg"))[:20]

# a replay must not lose frames: "block" (a live camera keeps the default, "drop")
with TrackingClient(connect=[endpoint], frame_congestion="block") as client:
    results = client.results("drone-1")  # subscribe first
    ack = client.start("drone-1", (393, 328, 155, 319), preset="arcf-h", frame_seq=0)
    for seq, path in enumerate(frames):
        client.publish_frame("drone-1", cv2.imread(str(path)), seq=seq)  # JPEG-encoded here
        r = results.get(timeout=10.0)  # the next result
        state = r.track_state.value if r.track_state else "-"  # no box, no state
        print(r.frame_seq, r.status.value, r.box, state, r.confidence, r.dropped)
    client.stop(ack.session_id)

"""Publish a real sequence as the frames of a stream at 10 fps, as a drone camera would.

    python replay_stream.py cam1 [FRAMES]      # boat1's JPEG files, numbered from 0
"""

import os
import sys
import time

from arcf.client import TrackingClient
from arcf.data import data_root

stream = sys.argv[1] if len(sys.argv) > 1 else "cam1"
count = int(sys.argv[2]) if len(sys.argv) > 2 else 100
paths = sorted((data_root() / "uav123_10fps/data_seq/boat1").glob("*.jpg"))

with TrackingClient(connect=[os.environ.get("ARCF_ENDPOINT", "tcp/127.0.0.1:7447")]) as client:
    for k in range(count):  # the files as they are: no decoding, no re-encoding
        client.publish_frame(stream, data=paths[k % len(paths)].read_bytes())
        time.sleep(0.1)
    print(f"{count} frames published on {stream!r}")

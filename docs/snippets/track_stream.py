"""Track a target on a stream that someone else publishes (a camera through arcf-ingest,
replay_stream.py): start a session on its next frame, read 30 results, stop.

    python track_stream.py gimbal
"""

import os
import sys

from arcf.client import TrackingClient

stream = sys.argv[1] if len(sys.argv) > 1 else "gimbal"
box = (393, 328, 155, 319)  # x, y, w, h on the stream's frames: boat1's boat

with TrackingClient(connect=[os.environ.get("ARCF_ENDPOINT", "tcp/127.0.0.1:7447")]) as client:
    results = client.results(stream)  # subscribe first
    ack = client.start(stream, box, preset="arcf-h")  # on the next frame that arrives
    for _ in range(30):  # 3 s of a 10 fps camera
        r = results.get(timeout=5.0)
        state = r.track_state.value if r.track_state else "-"  # no box, no state
        print(r.frame_seq, r.status.value, state, r.box)
    client.stop(ack.session_id)

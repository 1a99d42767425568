"""A minimal adapter: a protocol that speaks in shares of the picture (as MAVLink's tracking
status does) bridged to the service. It learns the stream's picture size from its frames,
starts a session on a box, and turns each result into a line: centre and size in shares of
the picture, or no box (a stale stream, an error, the session's end).

    python adapter.py cam1 393,328,155,319 [RESULTS]
"""

import os
import sys

from arcf.client import TrackingClient  # an adapter is a client: arcf.client, arcf.schemas
from arcf.client.media.encodings import codec_of
from arcf.schemas import Frame

stream = sys.argv[1] if len(sys.argv) > 1 else "cam1"
box = tuple(float(v) for v in (sys.argv[2] if len(sys.argv) > 2 else "393,328,155,319")
            .split(","))
count = int(sys.argv[3]) if len(sys.argv) > 3 else 20
size: dict[str, tuple[int, int]] = {}


def on_frame(frame: Frame) -> None:  # whoever publishes them: declared, else the header's
    codec = codec_of(frame.encoding)
    found = ((frame.width, frame.height) if frame.width and frame.height
             else codec.read_size(frame.payload) if codec.read_size else None)
    if found:
        size["picture"] = found


with TrackingClient(connect=[os.environ.get("ARCF_ENDPOINT", "tcp/127.0.0.1:7447")]) as client:
    client.frames(stream, callback=on_frame)
    results = client.results(stream)
    ack = client.start(stream, box, preset="arcf-h")  # a protocol's "track this" command
    print("frame,status,state,cx,cy,w,h")
    for _ in range(count):
        r = results.get(timeout=5.0)
        if r.track_state is None or "picture" not in size:  # no box to show
            print(f"{r.frame_seq},{r.status.value},,,,,")
            continue
        (W, H), (x, y, w, h) = size["picture"], r.box  # 1-based pixels
        print(f"{r.frame_seq},{r.status.value},{r.track_state.value},"
              f"{(x - 1 + w / 2) / W:.4f},{(y - 1 + h / 2) / H:.4f},{w / W:.4f},{h / H:.4f}")
    client.stop(ack.session_id)  # the protocol's "stop tracking"

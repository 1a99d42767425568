"""A station on the direct data path: a Zenoh peer of the service's router, which links to the
worker itself (the service runs with --worker-listen), so its frames skip the router."""

import os
import time

import cv2

from arcf.client import TrackingClient
from arcf.data import data_root

endpoint = os.environ.get("ARCF_ENDPOINT", "tcp/127.0.0.1:7447")  # the router, as always
frames = sorted((data_root() / "uav123_10fps/data_seq/boat1").glob("*.jpg"))[:10]

with TrackingClient(connect=[endpoint], mode="peer", frame_congestion="block") as client:
    # the router's gossip names the workers' endpoints; the links follow within a moment
    deadline = time.monotonic() + 10.0
    while not list(client.session.info.peers_zid()) and time.monotonic() < deadline:
        time.sleep(0.1)
    print("linked to", len(list(client.session.info.peers_zid())), "worker(s)")
    results = client.results("drone-1")
    ack = client.start("drone-1", (393, 328, 155, 319), preset="arcf-h", frame_seq=0)
    for seq, path in enumerate(frames):
        client.publish_frame("drone-1", cv2.imread(str(path)), seq=seq)
        r = results.get(timeout=10.0)
        print(r.frame_seq, r.status.value)
    client.stop(ack.session_id)

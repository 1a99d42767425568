"""Three simulated drones on a running service: boat1's first 100 frames each, 30 fps,
phases spread; what the service processed, its latency and every frame accounted for."""

import os
import time

from arcf.client import TrackingClient
from arcf.eval import load_dataset
from arcf.loadtools import Clip, Fleet, Pacing

endpoint = os.environ.get("ARCF_ENDPOINT", "tcp/127.0.0.1:7447")
clips = [Clip.of(s, limit=100) for s in load_dataset("uav123_10fps", sequences=["boat1"])]
with TrackingClient(connect=[endpoint]) as client, \
        Fleet(client, clips, preset="arcf-h", pacing=Pacing.fixed_rate(30)) as fleet:
    t0 = time.monotonic()
    fleet.add(3, frames=100)  # three drones, 30 fps each
    fleet.wait_published(timeout=30)
    fleet.settle()
    window = fleet.window(t0, time.monotonic())  # offered / processed fps, latency, drops
    print(window["processed_fps"], window["latency_ms"], fleet.ledger.accounting())

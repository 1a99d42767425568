"""MAVSDK as the ground station of arcf-mavlink: find the camera, read its video stream, track
a rectangle, print ten tracking statuses, stop.

    arcf-mavlink --camera cam1 --video cam1=rtsp://... --mavlink udpout:127.0.0.1:14550 &
    python mavsdk_station.py udpin://0.0.0.0:14550 0.30,0.45,0.42,0.90

The rectangle is the target's, in shares of the picture: left, top, right, bottom.
"""

import json
import sys
import time

from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.camera import Camera
from mavsdk.plugins.mavlink_direct import MavlinkDirect

url = sys.argv[1] if len(sys.argv) > 1 else "udpin://0.0.0.0:14550"
left, top, right, bottom = (float(v) for v in sys.argv[2].split(",")) if len(sys.argv) > 2 \
    else (0.4, 0.4, 0.6, 0.6)
STATES = {0: "IDLE", 1: "ACTIVE", 2: "ERROR", 3: "ACTIVE|COASTING"}


def wait_for(what, check, timeout=60.0):
    """MAVSDK fills its view of the camera as messages arrive: poll it, within a deadline."""
    deadline = time.monotonic() + timeout
    while not (value := check()):
        if time.monotonic() > deadline:
            sys.exit(f"no {what} within {timeout:.0f} s")
        time.sleep(0.1)
    return value


drone = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
drone.add_any_connection(url)
system = wait_for("camera", lambda: next((s for s in drone.get_systems() if s.has_camera()),
                                         None))
camera = Camera(system)
info = wait_for("camera information", lambda: camera.camera_list().cameras)[0]
comp = info.component_id
print(f"camera {comp} {info.model_name} "
      f"{info.horizontal_resolution_px}x{info.vertical_resolution_px}")
video = wait_for("video stream", lambda: camera.get_video_stream_info(comp).settings.uri)
print(f"video {video}")

# the Camera plugin has no call for the tracking status: MAVSDK's MavlinkDirect reads it
statuses = []
direct = MavlinkDirect(system)
direct.subscribe_message("CAMERA_TRACKING_IMAGE_STATUS",
                         lambda message, _user_data=None: statuses.append(
                             json.loads(message.fields_json)))  # NaN arrives as null
print(f"track_rectangle {camera.track_rectangle(comp, left, top, right, bottom).name}")
start = len(statuses)
wait_for("ten tracking statuses", lambda: len(statuses) >= start + 10)
for s in statuses[start:start + 10]:
    corners = [s[k] for k in ("rec_top_x", "rec_top_y", "rec_bottom_x", "rec_bottom_y")]
    where = " ".join("-" if v is None else f"{v:.3f}" for v in corners)
    print(f"status {STATES.get(s['tracking_status'], s['tracking_status'])} {where}")
print(f"track_stop {camera.track_stop(comp).name}")
idle = len(statuses)
wait_for("status after the stop", lambda: len(statuses) > idle, timeout=10)
print(f"status {STATES.get(statuses[-1]['tracking_status'])}")
direct.destroy()
camera.destroy()
drone.destroy()

"""The ROS 2 path: what ``arcf-ros2`` adds between a ROS 2 camera node and the tracker.

One service (1 worker), one ``Ros2Bridge``, and a ROS 2 camera node played with zenoh-python
and pycdr2 (as ``tests/adapters/test_ros2.py`` does). The same JPEG frames of a real sequence
go through two paths, each tracked by its own ARCF-HC session started on the first frame's
ground truth, frame by frame (each frame once the previous one's answer arrived):

* ROS 2: ``CompressedImage`` on rmw_zenoh's key -> bridge -> service -> bridge ->
  ``Detection2DArray``, timed from the image's put to the detection's arrival;
* direct: the SDK's ``publish_frame`` -> service -> ``result``, timed the same way.

The difference of the medians is what the adapter adds (CDR both ways, one more hop).

    python benchmarks/ros2_path.py                 # ~30 s
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from arcf.adapters import ros2_types as rt
from arcf.adapters.ros2 import Ros2Bridge, attachment, topic_key
from arcf.client import TrackingClient
from arcf.client.transport import open_session
from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.procs import ServiceProcess


def _lockstep(n: int, send: Callable[[int], object], answered: Callable[[], int]) -> list[float]:
    """Milliseconds from each send to its answer, one frame at a time."""
    out = []
    for i in range(n):
        t0 = time.perf_counter()
        send(i)
        deadline = time.monotonic() + 10
        while answered() <= i and time.monotonic() < deadline:
            time.sleep(0.0005)
        out.append(1e3 * (time.perf_counter() - t0))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default="wakeboard7")
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args(argv)
    (seq,) = load_dataset("uav123_10fps", sequences=[args.sequence])
    data = [p.read_bytes() for p in seq.frames[:args.frames]]
    x, y, w, h = np.asarray(seq.groundtruth)[0]
    service = ServiceProcess(workers=1)
    client = TrackingClient(connect=[service.endpoint], frame_congestion="block")
    bridge_client = TrackingClient(connect=[service.endpoint])
    bridge = Ros2Bridge(bridge_client, {"/camera/image/compressed": "ros"})
    node = open_session("client", connect=[service.endpoint])
    try:
        dets: list[float] = []
        out_key = topic_key(0, "/arcf/ros/detections", rt.DETECTION_2D_ARRAY)
        sub = node.declare_subscriber(out_key, lambda s: dets.append(time.perf_counter()))
        image_key = topic_key(0, "/camera/image/compressed", rt.COMPRESSED_IMAGE)
        gid = bytes(16)
        request = rt.message(
            rt.DETECTION_2D, header=rt.message("std_msgs/msg/Header", stamp=rt.message(
                "builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id=""), results=[],
            bbox=rt.message("vision_msgs/msg/BoundingBox2D", center=rt.message(
                "vision_msgs/msg/Pose2D", position=rt.message(
                    "vision_msgs/msg/Point2D", x=x - 1 + w / 2, y=y - 1 + h / 2), theta=0.0),
                size_x=float(w), size_y=float(h)), id="")
        node.put(topic_key(0, "/arcf/ros/track", rt.DETECTION_2D),
                 rt.serialize(request, rt.DETECTION_2D), attachment=attachment(1, 0, gid))
        while bridge.counts["starts"] < 1:
            time.sleep(0.01)

        def send_ros(i: int) -> None:
            image = rt.message(rt.COMPRESSED_IMAGE, header=rt.message(
                "std_msgs/msg/Header", stamp=rt.message(
                    "builtin_interfaces/msg/Time", sec=1000 + i, nanosec=0),
                frame_id="cam"), format="jpeg", data=np.frombuffer(data[i], np.uint8))
            node.put(image_key, rt.serialize(image, rt.COMPRESSED_IMAGE),
                     attachment=attachment(i + 1, time.time_ns(), gid))

        ros = _lockstep(len(data), send_ros, lambda: len(dets))

        results: list[object] = []
        rsub = client.results("direct", callback=results.append)
        client.start("direct", (x, y, w, h), preset="arcf-hc", frame_seq=0)
        direct = _lockstep(len(data),
                           lambda i: client.publish_frame("direct", data=data[i], seq=i),
                           lambda: len(results))
        sub.undeclare()
        rsub.close()
    finally:
        bridge.close()
        bridge_client.close()
        node.close()
        client.close()
        service.stop()
    r, d = np.array(ros[1:]), np.array(direct[1:])  # the first frame initialises
    print(f"{time.strftime('%Y-%m-%d')}, {describe()}")
    print(f"{args.sequence}, {len(r)} frames each, ARCF-HC, lock-step, 1 worker:")
    print(f"  ROS 2 (CompressedImage -> Detection2DArray): median {np.median(r):.1f} ms, "
          f"p95 {np.percentile(r, 95):.1f} ms")
    print(f"  direct (publish_frame -> result):            median {np.median(d):.1f} ms, "
          f"p95 {np.percentile(d, 95):.1f} ms")
    print(f"  added by the ROS 2 adapter: {np.median(r) - np.median(d):+.1f} ms (medians)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

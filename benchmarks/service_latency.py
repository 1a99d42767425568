"""Service overhead: per-frame latency through arcf-service versus the library alone.

For each (preset, sequence) the same JPEG frames are (a) decoded and tracked in this process by
the library, timing decode + init/update per frame, and (b) replayed through a real
``arcf-service`` on loopback in lock-step (one frame in flight, so no queueing), timing capture
timestamp -> result received by the client. The difference is what the service adds: msgpack,
Zenoh transport through the embedded router (both directions), and the worker's loop.

    python benchmarks/service_latency.py                 # arcf-h and arcf-hc, 2 sequences
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def library(preset: str, data: list[bytes], box) -> np.ndarray:  # type: ignore[no-untyped-def]
    import arcf
    from service.decoding import decode_compressed

    # decode + track per frame: what a service worker does with a frame
    out, t0 = [], time.perf_counter()
    frames = (decode_compressed(d) for d in data)  # as a worker decodes them
    for _ in arcf.track_frames(arcf.create_tracker(preset), frames, box):
        out.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
    return np.array(out)


def through_service(endpoint: str, preset: str, stream: str, data: list[bytes],
                    box) -> np.ndarray:  # type: ignore[no-untyped-def]
    from service.client import TrackingClient

    lat = []
    with TrackingClient(connect=[endpoint]) as client:
        results = client.results(stream)
        ack = client.start(stream, box, preset=preset, frame_seq=0)
        for i, d in enumerate(data):
            client.publish_frame(stream, data=d, seq=i)
            r = results.get(timeout=30)
            lat.append((time.time_ns() - r.capture_ts_ns) / 1e9)
        client.stop(ack.session_id)
        results.close()
    return np.array(lat)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", default="uav123_10fps:wakeboard7,dtb70:Animal3")
    ap.add_argument("--presets", default="arcf-h,arcf-hc")
    ap.add_argument("--frames", type=int, default=100)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    from arcf.eval import load_dataset

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "service.app", "--listen", endpoint,
                             "--metrics-port", "-1"], stdout=subprocess.PIPE, text=True,
                            cwd=ROOT, env=env)
    assert proc.stdout is not None
    print("#", proc.stdout.readline().strip(), file=sys.stderr)
    print(f"Machine: {os.cpu_count()} CPUs, {platform.processor() or 'x86_64'}; lock-step replay, "
          "one frame in flight; times in ms per frame.\n")
    print("| preset | sequence | frames | library: decode + track, mean / p50 / p99 | "
          "through the service: capture -> result, mean / p50 / p99 | overhead, mean / p50 |")
    print("| --- | --- | --- | --- | --- | --- |")
    try:
        for spec in args.sequences.split(","):
            ds, name = spec.split(":")
            (seq,) = load_dataset(ds, sequences=[name])
            data = [p.read_bytes() for p in seq.frames[: args.frames]]
            for preset in args.presets.split(","):
                lib = library(preset, data, seq.init_box) * 1e3
                svc = through_service(endpoint, preset, f"{name}-{preset}", data,
                                      seq.init_box) * 1e3
                d = svc - lib
                print(f"| {preset} | {name} | {len(data)} | {lib.mean():.1f} / "
                      f"{np.percentile(lib, 50):.1f} / {np.percentile(lib, 99):.1f} | "
                      f"{svc.mean():.1f} / {np.percentile(svc, 50):.1f} / "
                      f"{np.percentile(svc, 99):.1f} | {d.mean():.1f} / "
                      f"{np.percentile(d, 50):.1f} |", flush=True)
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

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
import time

import cv2
import numpy as np

import arcf
from arcf.client import TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.driver import Clip, Fleet, Pacing
from arcf.loadtools.procs import ServiceProcess


def library(preset: str, clip: Clip) -> np.ndarray:
    """Seconds per frame of decode + track in this process: what a service worker does."""
    out, t0 = [], time.perf_counter()
    frames = (decode_compressed(d) for d in clip.frames)  # as a worker decodes them
    for _ in arcf.track_frames(arcf.create_tracker(preset), frames, clip.box):
        out.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
    return np.array(out)


def through_service(client: TrackingClient, preset: str, clip: Clip) -> np.ndarray:
    """Seconds from capture to result received per frame, one frame in flight (lock-step)."""
    with Fleet(client, [clip], preset=preset, pacing=Pacing.lock_step()) as fleet:
        (stream,) = fleet.add(names=[f"{clip.name}-{preset}"], frames=len(clip))
        fleet.wait_published(timeout=30.0 * len(clip))
        fleet.settle(timeout=30)
    got = sorted(stream.record.received, key=lambda r: r.frame_seq)
    if [r.frame_seq for r in got] != list(range(len(clip))):
        raise RuntimeError(f"{stream.name}: not one result per frame "
                           f"({len(got)} results for {len(clip)} frames)")
    return np.array([r.latency_s for r in got])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", default="uav123_10fps:wakeboard7,dtb70:Animal3")
    ap.add_argument("--presets", default="arcf-h,arcf-hc")
    ap.add_argument("--frames", type=int, default=100)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    arcf.warm_up()  # the kernels compiled before timing, as a worker has them when it starts
    svc = ServiceProcess(workers=os.cpu_count() or 1, metrics=False, quiet=False,
                         env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"})
    print(f"# {svc.ready_line}")
    print(f"Machine: {describe()}; lock-step replay, "
          "one frame in flight; times in ms per frame.\n")
    print("| preset | sequence | frames | library: decode + track, mean / p50 / p99 | "
          "through the service: capture -> result, mean / p50 / p99 | overhead, mean / p50 |")
    print("| --- | --- | --- | --- | --- | --- |")
    try:
        client = TrackingClient(connect=[svc.endpoint])
        for spec in args.sequences.split(","):
            ds, name = spec.split(":")
            (seq,) = load_dataset(ds, sequences=[name])
            clip = Clip.of(seq, limit=args.frames)
            for preset in args.presets.split(","):
                lib = library(preset, clip) * 1e3
                through = through_service(client, preset, clip) * 1e3
                d = through - lib
                print(f"| {preset} | {name} | {len(clip)} | {lib.mean():.1f} / "
                      f"{np.percentile(lib, 50):.1f} / {np.percentile(lib, 99):.1f} | "
                      f"{through.mean():.1f} / {np.percentile(through, 50):.1f} / "
                      f"{np.percentile(through, 99):.1f} | {d.mean():.1f} / "
                      f"{np.percentile(d, 50):.1f} |", flush=True)
        client.close()
    finally:
        svc.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

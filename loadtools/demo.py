"""``arcf-demo``: start the service on its embedded default and replay a real sequence through it.

    arcf-demo                                  # UAV123@10fps wakeboard7 at 10 fps, arcf-hc
    arcf-demo --dataset dtb70 --sequence Animal3 --preset arcf-h --fps 30 --limit 100
    arcf-demo --encoding h264                  # the same frames as a drone's H.264 video
    arcf-demo -e tcp/127.0.0.1:7447 --stream cam1   # through a service that is already running

The service runs as a child process (its own embedded Zenoh router on loopback), exactly as
``arcf-service`` would, unless ``--connect`` names a running one; this process is a ground
station: it publishes the JPEG frames, starts a tracking session from the ground truth's first
box and prints each result as it arrives.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Iterator

import numpy as np
import zenoh

from arcf.client import TrackingClient
from arcf.client.transport import ZENOH_SHORT_FLAGS
from arcf.eval import load_dataset

from .driver import Clip, Fleet, Pacing, SimulatedStream
from .ledger import Received, percentiles
from .procs import ServiceProcess


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="arcf-demo", description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--sequence", default="wakeboard7")
    ap.add_argument("--preset", default="arcf-hc")
    ap.add_argument("--fps", type=float, default=10.0, help="replay rate (0: as fast as possible)")
    ap.add_argument("--limit", type=int, default=0, help="replay only the first N frames")
    ap.add_argument("--port", type=int, default=7447,
                    help="the started service's router port (loopback)")
    ap.add_argument("--workers", type=int, default=0,
                    help="the started service's workers (default: cores)")
    ap.add_argument(ZENOH_SHORT_FLAGS["connect"], "--connect", action="append",
                    metavar="ENDPOINT", help="a running service's Zenoh endpoint (repeatable): "
                    "replay through it instead of starting one")
    ap.add_argument("--stream", default="", help="the stream's name (default: "
                    "<dataset>-<sequence>)")
    ap.add_argument("--encoding", choices=("jpeg", "h264", "h265"), default="jpeg",
                    help="send the frames as JPEG files or as H.264 / H.265 video")
    args = ap.parse_args(argv)

    (seq,) = load_dataset(args.dataset, sequences=[args.sequence])
    clip = Clip.of(seq, limit=args.limit)
    if args.encoding != "jpeg":
        clip = clip.as_video(args.encoding)
    gt = np.asarray(seq.groundtruth, dtype=float)
    errors: list[float] = []

    def show(stream: SimulatedStream, got: Received) -> None:
        r = got.result
        if got.status in ("stopped", "stale"):  # about no frame: no box to score
            print(f"{got.status}: {r.message}", flush=True)
            return
        x, y, w, h = r.box
        g = gt[r.frame_seq]
        err = float(np.hypot(x + w / 2 - g[0] - g[2] / 2, y + h / 2 - g[1] - g[3] / 2))
        errors.append(err)
        state = r.track_state.value if r.track_state else "-"
        confidence = f"{r.confidence:.2f}" if r.confidence is not None else "   -"
        print(f"frame {r.frame_seq:4d} {got.status:13s} box ({x:7.1f}, {y:7.1f}, {w:6.1f}, "
              f"{h:6.1f}) {state:8s} confidence {confidence} "
              f"psr {r.psr:5.1f} aberrance {r.aberrance:.4f} "
              f"dropped {r.dropped} error {err:5.1f} px", flush=True)

    with _service(args) as endpoints:
        try:
            client = TrackingClient(connect=endpoints)
        except zenoh.ZError as e:  # no router there
            raise SystemExit(f"arcf-demo: no service at {', '.join(endpoints)} ({e})") from e
        with client:
            fleet = Fleet(client, [clip], preset=args.preset, pacing=Pacing(fps=args.fps),
                          on_result=show)
            name = args.stream or f"{args.dataset}-{args.sequence}"
            (stream,) = fleet.add(names=[name], frames=len(clip))
            print(f"session {stream.sessions[0]} on stream {stream.name}: "
                  f"{stream.acks[0].message}", flush=True)
            print("each result: frame, status, box (x, y, w, h: 1-based pixels), track state, "
                  "confidence, PSR, aberrance, frames dropped before it, and the box centre's "
                  "distance to the ground truth's", flush=True)
            fleet.wait_published(timeout=len(clip) * 10.0)
            fleet.settle(timeout=10)
            fleet.close()
        received = stream.record.received
        lat = percentiles([r.latency_s for r in received])
        print(f"\n{len(received)}/{len(clip)} frames tracked; end-to-end latency p50 "
              f"{lat['p50']:.1f} ms, p99 {lat['p99']:.1f} ms; mean centre error vs ground "
              f"truth {np.nanmean(errors):.1f} px", flush=True)
    return 0


@contextlib.contextmanager
def _service(args: argparse.Namespace) -> Iterator[list[str]]:
    """The endpoints to replay through: ``--connect``'s, or a service started for the run
    (stopped after it)."""
    if args.connect:
        yield list(args.connect)
        return
    print(f"starting arcf-service on tcp/127.0.0.1:{args.port}", flush=True)
    try:
        service = ServiceProcess(listen=f"tcp/127.0.0.1:{args.port}",
                                 workers=args.workers or os.cpu_count() or 1, quiet=False)
    except RuntimeError as e:
        raise SystemExit(f"arcf-demo: the service did not start ({e})") from e
    try:
        print(service.ready_line, flush=True)
        yield [service.endpoint]
    finally:
        service.stop()


if __name__ == "__main__":
    sys.exit(main())

"""``arcf-demo``: start the service on its embedded default and replay a real sequence through it.

    arcf-demo                                  # UAV123@10fps wakeboard7 at 10 fps, arcf-hc
    arcf-demo --dataset dtb70 --sequence Animal3 --preset arcf-h --fps 30 --limit 100

The service runs as a child process (its own embedded Zenoh router on loopback), exactly as
``arcf-service`` would; this process is a ground station: it publishes the JPEG frames, starts a
tracking session from the ground truth's first box and prints each result as it arrives.
"""

from __future__ import annotations

import argparse
import os
import queue
import subprocess
import sys
import time

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="arcf-demo", description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--sequence", default="wakeboard7")
    ap.add_argument("--preset", default="arcf-hc")
    ap.add_argument("--fps", type=float, default=10.0, help="replay rate (0: as fast as possible)")
    ap.add_argument("--limit", type=int, default=0, help="replay only the first N frames")
    ap.add_argument("--port", type=int, default=7447)
    ap.add_argument("--workers", type=int, default=0, help="service workers (default: cores)")
    args = ap.parse_args(argv)

    from arcf.eval import load_dataset

    from .client import TrackingClient

    (seq,) = load_dataset(args.dataset, sequences=[args.sequence])
    n = min(len(seq), args.limit) if args.limit else len(seq)
    endpoint = f"tcp/127.0.0.1:{args.port}"
    cmd = [sys.executable, "-m", "service.app", "--listen", endpoint, "--metrics-port", "0"]
    if args.workers:
        cmd += ["--workers", str(args.workers)]
    print(f"starting: {' '.join(cmd)}", flush=True)
    service = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        assert service.stdout is not None
        ready = service.stdout.readline().strip()
        if not ready.startswith("arcf-service ready"):
            raise SystemExit(f"arcf-demo: the service did not start ({ready!r})")
        print(ready, flush=True)
        with TrackingClient(connect=[endpoint]) as client:
            stream = f"{args.dataset}-{args.sequence}"
            results = client.results(stream)
            ack = client.start(stream, seq.init_box, preset=args.preset, frame_seq=0)
            print(f"session {ack.session_id} on stream {stream}: {ack.message}", flush=True)
            period = 1.0 / args.fps if args.fps > 0 else 0.0
            t0 = time.monotonic()
            received, latencies, gt_err = 0, [], []
            for i in range(n):
                client.publish_frame(stream, data=seq.frames[i].read_bytes(), seq=i)
                received += _drain(results, latencies, gt_err, seq, block=False)
                if period:
                    time.sleep(max(0.0, t0 + (i + 1) * period - time.monotonic()))
            deadline = time.monotonic() + 10
            while received < n and time.monotonic() < deadline:
                received += _drain(results, latencies, gt_err, seq, block=True)
            client.stop(ack.session_id)
            lat = np.array(latencies) * 1e3
            print(f"\n{received}/{n} frames tracked; end-to-end latency p50 "
                  f"{np.percentile(lat, 50):.1f} ms, p99 {np.percentile(lat, 99):.1f} ms; mean "
                  f"centre error vs ground truth {np.nanmean(gt_err):.1f} px", flush=True)
            results.close()
    finally:
        service.terminate()
        service.wait(timeout=15)
    return 0


def _drain(results, latencies, gt_err, seq, block: bool) -> int:  # type: ignore[no-untyped-def]
    got = 0
    while True:
        try:
            r = results.get(timeout=0.5 if block and got == 0 else 0)
        except queue.Empty:
            return got
        got += 1
        latencies.append((r.published_ts_ns - r.capture_ts_ns) / 1e9)
        x, y, w, h = r.box
        g = seq.groundtruth[r.frame_seq]
        err = float(np.hypot(x + w / 2 - g[0] - g[2] / 2, y + h / 2 - g[1] - g[3] / 2))
        gt_err.append(err)
        status = getattr(r.status, "value", str(r.status))
        print(f"frame {r.frame_seq:4d} {status:13s} box ({x:7.1f}, {y:7.1f}, {w:6.1f}, "
              f"{h:6.1f}) peak {r.peak:.3f} psr {r.psr:5.1f} aberrance {r.aberrance:.4f} "
              f"dropped {r.dropped} error {err:5.1f} px", flush=True)


if __name__ == "__main__":
    sys.exit(main())

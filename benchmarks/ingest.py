"""What ``arcf-ingest`` adds between a camera and the service: the latency from a unit leaving
the camera's muxer to its frame reaching a station subscribed to the stream, and the
ingest's CPU per frame, for RTP/UDP (no SDP), MPEG-TS/UDP and RTSP (GStreamer's server).

A 1280x720 30 fps H.264 camera (a shared sequence, libx264 veryfast, keyframes every 10,
parameter sets before each) is sent on loopback by FFmpeg's muxers (PyAV); ``arcf-ingest``
runs as its own process against a service's router; the station is this process. Figures
cover the units after the first two seconds (the source's probing holds the first ones).

    python benchmarks/ingest.py                     # about a minute
    python benchmarks/ingest.py --sources rtp --seconds 20
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from arcf.client import TrackingClient
from arcf.client.media.images import decode_compressed
from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.procs import ServiceProcess, free_port
from arcf.loadtools.senders import (
    RtspServer,
    VideoSender,
    free_rtp_port,
    rtsp_server_problem,
    write_video_file,
)
from arcf.loadtools.video import encode_video
from arcf.loadtools.waiting import wait_until
from arcf.schemas import Frame

FPS, GOP = 30, 10


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (and its threads)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(kind: str, units: list[bytes], size: tuple[int, int], seconds: float,
        service: ServiceProcess, workdir: Path) -> dict[str, float]:
    repeat = max(1, round(seconds * FPS / len(units)))
    stream = f"bench-{kind}"
    arrived: dict[int, int] = {}
    lock = threading.Lock()

    def on_frame(frame: Frame) -> None:
        with lock:
            arrived[frame.seq] = time.time_ns()

    server = None
    if kind == "rtp":
        port = free_rtp_port()
        source, url, fmt = f"rtp://127.0.0.1:{port}", f"rtp://127.0.0.1:{port}", "rtp"
    elif kind == "mpegts":
        port = free_port()
        source, url, fmt = (f"udp://127.0.0.1:{port}", f"udp://127.0.0.1:{port}?pkt_size=1316",
                            "mpegts")
    else:
        ts = write_video_file(units * repeat, workdir / "cam.ts", size)
        server = RtspServer(ts, free_port())
        source, url, fmt = server.url, "", ""
    with TrackingClient(connect=[service.endpoint]) as client:
        watch = client.frames(stream, callback=on_frame)
        ingest = subprocess.Popen([sys.executable, "-m", "arcf.adapters.ingest", source,
                                   "--stream", stream, "-e", service.endpoint],
                                  stderr=subprocess.DEVNULL)
        try:
            sent: dict[int, int] = {}
            if server is None:
                time.sleep(2.0)  # the ingest is up and listening before the camera starts
                t_start = time.time_ns()
                sender = VideoSender(units, url, fmt, size, repeat=repeat).start()
            else:  # the server paces the file from the ingest's connection
                wait_until(lambda: len(arrived) > 0, timeout=60, what="the first frame")
            # the CPU window: from the third second to a second before the camera stops
            time.sleep(2.0)
            c0, t0, n0 = cpu_s(ingest.pid), time.monotonic(), len(arrived)
            time.sleep(max(1.0, seconds - 3.0))
            c1, t1, n1 = cpu_s(ingest.pid), time.monotonic(), len(arrived)
            if server is None:
                wait_until(lambda: sender.done, timeout=seconds * 3 + 60, what="sent")
                time.sleep(1.0)  # the last units through
                sent = {k: t_start + int(k * 1e9 / FPS) for k in range(sender.sent)}
            steady = [k for k in arrived if k >= 2 * FPS]
        finally:
            ingest.terminate()
            ingest.wait(30)
            watch.close()
            if server is not None:
                server.stop()
    with lock:
        got = dict(arrived)
    out = {"frames": float(len(got))}
    if sent:
        lat = np.array([(got[k] - sent[k]) / 1e6 for k in steady if k in sent and k in got])
        # the sender's schedule, not its mux call, is the reference: a late mux is the camera's
        out.update(latency_median_ms=float(np.median(lat)), latency_p95_ms=float(
            np.percentile(lat, 95)), latency_n=float(len(lat)))
    if n1 > n0:
        out["cpu_ms_per_frame"] = 1e3 * (c1 - c0) / (n1 - n0)
    out["cpu_share"] = (c1 - c0) / (t1 - t0)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sources", default="rtp,mpegts,rtsp")
    ap.add_argument("--seconds", type=float, default=12.0, help="per source")
    args = ap.parse_args(argv)
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    images = [decode_compressed(p.read_bytes()) for p in seq.frames[:60]]
    units = encode_video(images, "h264", fps=FPS, gop=GOP, repeat_headers=True)
    size = (images[0].shape[1], images[0].shape[0])
    print(f"# python benchmarks/ingest.py {' '.join(argv or sys.argv[1:])}")
    print(f"# {datetime.date.today()}, {describe()}")
    print(f"# camera: {size[0]}x{size[1]} H.264 at {FPS} fps, mean "
          f"{np.mean([len(u) for u in units]) / 1e3:.0f} kB a unit, keyframe every {GOP}")
    print("\n| source | frames | latency median / p95 (ms) | ingest CPU per frame (ms) | "
          "ingest CPU (share of a core) |\n| --- | --- | --- | --- | --- |")
    with ServiceProcess(workers=1) as service, \
            tempfile.TemporaryDirectory() as tmp:
        for kind in args.sources.split(","):
            if kind == "rtsp" and (problem := rtsp_server_problem()):
                print(f"| rtsp | skipped: {problem} | | | |")
                continue
            r = run(kind, units, size, args.seconds, service, Path(tmp))
            lat = (f"{r['latency_median_ms']:.1f} / {r['latency_p95_ms']:.1f}"
                   if "latency_median_ms" in r else "n/a (the server paces)")
            per = f"{r['cpu_ms_per_frame']:.2f}" if "cpu_ms_per_frame" in r else "n/a"
            print(f"| {kind} | {int(r['frames'])} | {lat} | {per} | {r['cpu_share']:.3f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

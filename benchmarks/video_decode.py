"""Decoding cost of a 1280x720 stream: H.264 access units
(``arcf.client.media.video.StreamDecoder``) next to JPEG frames
(``arcf.client.media.images.decode_compressed``, what a worker does), on the same real
frames, single-threaded; and the memory one stream's decoder holds.

    python benchmarks/video_decode.py            # ~20 s
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import av
import cv2
import numpy as np

from arcf.client.media.images import decode_compressed
from arcf.client.media.video import StreamDecoder
from arcf.data import data_root
from arcf.eval.environment import describe


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default="uav123_10fps/data_seq/wakeboard7")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--streams", type=int, default=8, help="decoders for the memory figure")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    paths = sorted((data_root() / args.sequence).glob("*.jpg"))[:args.frames]
    jpegs = [p.read_bytes() for p in paths]
    images = [decode_compressed(j) for j in jpegs]
    h, w = images[0].shape[:2]
    enc = av.CodecContext.create("libx264", "w")
    enc.width, enc.height, enc.pix_fmt, enc.framerate = w, h, "yuv420p", Fraction(30)
    enc.options = {"g": "30", "bf": "0", "preset": "veryfast", "tune": "zerolatency"}
    units = [bytes(p) for im in images
             for p in enc.encode(av.VideoFrame.from_ndarray(im, "bgr24"))]
    units += [bytes(p) for p in enc.encode(None)]

    def timed(fn, items) -> np.ndarray:
        out = []
        for i, item in enumerate(items):
            t0 = time.perf_counter()
            fn(i, item)
            out.append(1e3 * (time.perf_counter() - t0))
        return np.array(out)

    dec = StreamDecoder("h264")
    t_h264 = timed(dec.decode, units)
    t_jpeg = timed(lambda _i, j: decode_compressed(j), jpegs)
    base = rss_mb()
    decoders = [StreamDecoder("h264") for _ in range(args.streams)]
    for d in decoders:
        for i, u in enumerate(units[:30]):
            d.decode(i, u)
    per_stream = (rss_mb() - base) / args.streams
    print(f"{w}x{h}, {len(units)} frames of {args.sequence}, 1 thread; "
          f"{time.strftime('%Y-%m-%d')}, {describe()}, PyAV {av.__version__}:")
    unit_kb = np.mean([len(u) for u in units]) / 1e3
    print(f"  H.264 (libx264 veryfast, keyframe every 30, mean {unit_kb:.1f} kB/unit): "
          f"decode median {np.median(t_h264):.2f} ms, p95 {np.percentile(t_h264, 95):.2f} ms")
    print(f"  JPEG (the sequence's files, mean {np.mean([len(j) for j in jpegs]) / 1e3:.1f} kB): "
          f"decode median {np.median(t_jpeg):.2f} ms, p95 {np.percentile(t_jpeg, 95):.2f} ms")
    print(f"  memory: {per_stream:.1f} MB RSS per stream's decoder ({args.streams} decoders, "
          "each after 30 units)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What a worker's JPEG decode costs where the tracker reads, with and without restart markers.

A tracker runs over a real sequence and says, frame by frame, which rows and columns its next
update reads (``read_region``); each frame is then decoded as a worker decodes it
(``arcf.client.media.encodings.decode_image`` with that region) and whole, in CPU ms per
frame, single-threaded:

- the sequence's own files (no restart markers: libjpeg reads every row above the region);
- the same pictures encoded at quality 90 without restart markers, with a restart interval
  per MCU row, and as the client SDK sends them (``encode_image``: quality 90, intervals of
  8 MCUs, 128 pixels): with restart markers the decoder reads only the intervals that cover
  the region (``_jpegregion``'s restart seek), the rows above and, with intervals shorter
  than a row, the columns beside it left unread.

    python benchmarks/jpeg_region.py                      # arcf-h on wakeboard7
    python benchmarks/jpeg_region.py --preset arcf-hc --sequence boat1

The machine should be otherwise idle.
"""

from __future__ import annotations

import sys
import time
from datetime import UTC, datetime
from typing import Any

from _common import parser  # beside this script


def _cpu_ms(decode: Any, payloads: list[bytes], regions: list[Any], repeat: int) -> float:
    """Mean CPU ms of ``decode(payload, region)`` over the frames, ``repeat`` rounds."""
    for payload, region in zip(payloads, regions, strict=True):  # warm: caches, allocator
        decode(payload, region)
    c0 = time.thread_time()
    for _ in range(repeat):
        for payload, region in zip(payloads, regions, strict=True):
            decode(payload, region)
    return 1e3 * (time.thread_time() - c0) / (repeat * len(payloads))


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__, preset="arcf-h")
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--sequence", default="wakeboard7")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)

    from types import SimpleNamespace

    import cv2
    import numpy as np

    import arcf
    from arcf.client.media import _jpegregion
    from arcf.client.media.encodings import decode_image, encode_image
    from arcf.client.media.images import decode_compressed
    from arcf.eval import load_dataset
    from arcf.eval.environment import describe
    from arcf.region import whole_frame

    cv2.setNumThreads(1)
    (seq,) = load_dataset(args.dataset, sequences=[args.sequence])
    files = [p.read_bytes() for p in seq.frames[:args.frames]]
    images = [decode_compressed(f) for f in files]
    h, w = images[0].shape[:2]
    tracker = arcf.create_tracker(args.preset)
    regions: list[Any] = [None]
    tracker.init(images[0], tuple(seq.groundtruth[0]))
    for image in images[1:]:
        regions.append(tracker.read_region())
        tracker.update(whole_frame(image))
    sent = [encode_image(image, "jpeg", 90) for image in images]

    def encoded(*params: int) -> list[bytes]:
        return [cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90, *params])[1]
                .tobytes() for image in images]

    plain = encoded()
    rows = encoded(cv2.IMWRITE_JPEG_RST_INTERVAL, -(-w // 16))

    def region_decode(payload: bytes, region: Any) -> Any:
        frame = SimpleNamespace(encoding="jpeg", payload=payload, width=None, height=None)
        return decode_image(frame, 1 << 26, region)

    def whole(payload: bytes, region: Any) -> Any:
        return decode_compressed(payload)

    read = [r for r in regions if r is not None]
    share = np.mean([(b - t) * (r - lf) for t, lf, b, r in read]) / (h * w) if read else 1.0
    seeks = [_jpegregion.seek(p, max(r[0] - 8, 0), max(r[1] - 8, 0), r[2] + 8, r[3] + 8)
             for p, r in zip(sent, regions, strict=True) if r is not None]
    skipped = [(s[0] * w + s[1]) / (h * w) if s else 0.0 for s in seeks]
    print(f"# python benchmarks/jpeg_region.py {' '.join(sys.argv[1:])}".rstrip())
    print(f"# {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, {describe()}")
    print(f"# {args.preset} on {args.sequence}: {len(files)} frames of {w}x{h}; the tracker "
          f"reads {100 * share:.0f} % of the picture on average "
          f"({len(regions) - len(read)} frames whole); the SDK's restart intervals leave "
          f"unread the {100 * np.mean(skipped):.0f} % of the picture before the first interval "
          "covering it, and the columns beside it\n")
    print("| frames | bytes / frame | whole decode (ms) | where the tracker reads (ms) |")
    print("| --- | --- | --- | --- |")
    for name, payloads in (("the sequence's files", files),
                           ("quality 90, no restart markers", plain),
                           ("quality 90, a restart interval per MCU row", rows),
                           ("quality 90, intervals of 8 MCUs (the SDK's)", sent)):
        print(f"| {name} | {np.mean([len(p) for p in payloads]):,.0f} | "
              f"{_cpu_ms(whole, payloads, regions, args.repeat):.2f} | "
              f"{_cpu_ms(region_decode, payloads, regions, args.repeat):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

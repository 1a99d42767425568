"""What a frame costs the service besides its tracking, stage by stage.

One service (one worker, its embedded Zenoh router in the main process), one stream of a real
sequence at a camera's rate, one session; the same frames through the library alone in this
process (decode + track, one thread). Per frame, in CPU milliseconds:

- the worker's stages (``arcf_stage_cpu_seconds_total``, ``service/stages.py``): receive,
  parse, decode, convert, track, publish, metrics; "worker, the rest" is the worker process's
  CPU time (``/proc``) minus their sum: Zenoh's own threads, the loop, housekeeping;
- the main process: the embedded router forwarding every frame and result, the control plane
  and the metrics endpoint (with an external router, that part moves to the router);
- the overhead: everything but the track stage, worker and main process together;
- the queue: how long a frame waited in its stream's queue before the worker took it
  (``arcf_queue_wait_seconds``, wall time: what latency, not CPU, a frame spends there);
- the library alone, back to back and paced at the stream's rate (a worker that waits for
  its next frame finds its caches cold: the same tracking costs more CPU than back to back).

    python benchmarks/service_profile.py            # arcf-h on wakeboard7, JPEG and H.264
    python benchmarks/service_profile.py --preset arcf-hc --sequence boat1 --encodings jpeg
    python benchmarks/service_profile.py --encodings jpeg,jpeg-sdk   # restart intervals
    python benchmarks/service_profile.py --encodings jpeg-sdk --path direct  # --worker-listen

``--path direct`` runs the worker with ``--worker-listen`` and the station as a Zenoh peer
linked to it: frames and results do not cross the router.

The machine should be otherwise idle: the generator (this process) runs beside the service.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from _common import parser  # beside this script

ROOT = Path(__file__).resolve().parent.parent
MAIN = "main process (control, metrics; the router, if embedded)"
ROUTER = "external router"
QUEUE = "queue: a frame's wait before its worker takes it (wall ms, not CPU)"


def library_alone(clip: Any, preset: str, frames: int, pace_s: float = 0.0) -> dict[str, float]:
    """Decode + track the clip's frames in this process: CPU ms per frame of each, back to
    back, or sleeping ``pace_s`` after each frame as a camera's stream leaves a worker idle
    (caches go cold between frames: the same work costs more CPU). A video picture's "decode"
    includes its conversion to BGR (the service counts it apart, as "convert")."""
    import cv2
    import numpy as np

    import arcf
    from arcf.client.media.encodings import codec_of
    from arcf.client.media.images import decode_compressed

    cv2.setNumThreads(1)
    tracker = arcf.create_tracker(preset)
    codec = codec_of(clip.encoding)
    decoder = codec.stream_decoder() if codec.is_video else None
    decode_s = track_s = 0.0
    n = 0
    for i in range(frames):
        data = clip.frames[i % len(clip)]
        c0 = time.thread_time()
        image: np.ndarray | None = (decode_compressed(data) if decoder is None
                                    else decoder.decode(i, data).image)
        c1 = time.thread_time()
        if image is None:
            continue
        if i % len(clip) == 0:
            tracker.init(image, clip.box)
        else:
            tracker.update(image)
        c2 = time.thread_time()
        decode_s += c1 - c0
        track_s += c2 - c1
        n += 1
        if pace_s:
            time.sleep(pace_s)
    return {"decode": 1e3 * decode_s / n, "track": 1e3 * track_s / n}


def service_run(clip: Any, preset: str, frames: int, fps: float,
                external_router: bool, direct: bool = False) -> dict[str, float]:
    """One stream through a real service; CPU ms per frame by stage and by process."""
    from contextlib import ExitStack

    from arcf.client import TrackingClient
    from arcf.loadtools.driver import Fleet, Pacing
    from arcf.loadtools.procs import RouterProcess, ServiceProcess
    from arcf.loadtools.system import cpu_seconds
    from arcf.loadtools.waiting import wait_for_peers
    from arcf.service.scrape import by_label, fetch, totals
    from arcf.service.stages import STAGES

    def waited() -> tuple[float, float]:
        assert svc.metrics_url
        t = totals(fetch(svc.metrics_url))
        return (t.get("arcf_queue_wait_seconds_sum", 0.0),
                t.get("arcf_queue_wait_seconds_count", 0.0))

    with ExitStack() as stack:
        router = stack.enter_context(RouterProcess()) if external_router else None
        svc = stack.enter_context(ServiceProcess(
            *(("--worker-listen", "tcp/127.0.0.1:0") if direct else ()),
            workers=1, connect=router.endpoint if router else None))
        (worker,) = svc.workers
        router_cpu = (lambda: cpu_seconds(router.proc.pid)) if router else (lambda: 0.0)
        with TrackingClient(connect=[svc.endpoint], frame_congestion="block",
                            mode="peer" if direct else "client") as client, \
                Fleet(client, [clip], preset=preset, pacing=Pacing.fixed_rate(fps)) as fleet:
            if direct:
                wait_for_peers(client.session)
            # re-initialised where the clip starts over, as the library run below is: a tracker
            # that jumped back to the first frame would be searching the whole frame
            (stream,) = fleet.add(frames=frames, hold=True, reinit_on_wrap=True)
            time.sleep(1.0)  # the session's start and first housekeeping out of the window
            assert svc.metrics_url
            stages0 = by_label(fetch(svc.metrics_url), "arcf_stage_cpu_seconds_total", "stage")
            main0, worker0, router0 = cpu_seconds(svc.proc.pid), cpu_seconds(worker), router_cpu()
            wait0 = waited()
            fleet.release()
            if not fleet.wait_published(timeout=10 + 3 * frames / fps):
                raise SystemExit("not every frame was published")
            fleet.settle(timeout=30)
            main1, worker1, router1 = cpu_seconds(svc.proc.pid), cpu_seconds(worker), router_cpu()
            # the worker adds its stage times once a second (an idle one wakes every 0.5 s):
            # read until two readings 2 s apart agree
            stages1 = by_label(fetch(svc.metrics_url), "arcf_stage_cpu_seconds_total", "stage")
            for _ in range(10):
                time.sleep(2.0)
                again = by_label(fetch(svc.metrics_url), "arcf_stage_cpu_seconds_total", "stage")
                if again == stages1:
                    break
                stages1 = again
            answered = len({r.frame_seq for r in stream.record.received})
            wait1 = waited()
    if answered < frames:
        print(f"# {frames - answered} frames without a result", file=sys.stderr)
    per = 1e3 / answered
    out = {s: per * (stages1.get(s, 0.0) - stages0.get(s, 0.0)) for s in STAGES}
    out["worker, the rest"] = per * (worker1 - worker0) - sum(out[s] for s in STAGES)
    out[MAIN] = per * (main1 - main0)
    out[ROUTER] = per * (router1 - router0)
    out["answered"] = answered
    out[QUEUE] = 1e3 * (wait1[0] - wait0[0]) / max(wait1[1] - wait0[1], 1.0)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__, preset="arcf-h", fps=30.0)
    ap.add_argument("--sequence", default="wakeboard7")
    ap.add_argument("--encodings", default="jpeg,h264")
    ap.add_argument("--frames", type=int, default=600, help="frames sent (the clip looped)")
    ap.add_argument("--router", choices=("embedded", "external"), default="embedded",
                    help="the service's own router, or a separate arcf-router it connects to")
    ap.add_argument("--path", choices=("router", "direct"), default="router",
                    help="frames through the router, or straight to the worker (a peer "
                    "station, --worker-listen)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))

    import arcf
    from arcf.eval import load_dataset
    from arcf.eval.environment import describe
    from arcf.loadtools.driver import Clip
    from arcf.service.stages import STAGES

    arcf.warm_up()
    seq = next(s for ds in ("uav123_10fps", "dtb70", "uavdt") for s in load_dataset(ds)
               if s.name == args.sequence)
    jpeg = Clip.of(seq)
    columns: dict[str, dict[str, float]] = {}
    alone: dict[str, dict[str, float]] = {}
    for encoding in [e for e in args.encodings.split(",") if e]:
        clip = (jpeg if encoding == "jpeg" else jpeg.as_sent() if encoding == "jpeg-sdk"
                else jpeg.as_video(encoding))
        n = min(args.frames, 3 * len(clip))
        alone[encoding] = library_alone(clip, args.preset, n)
        paced = library_alone(clip, args.preset, n, 1 / args.fps)
        alone[encoding].update({f"paced {k}": v for k, v in paced.items()})
        columns[encoding] = service_run(clip, args.preset, args.frames, args.fps,
                                        args.router == "external", args.path == "direct")
    h, w = seq.read_frame(0).shape[:2]
    print(f"`python benchmarks/service_profile.py {' '.join(argv or sys.argv[1:])}`"
          .replace(" `", "`"))
    print(f"{time.strftime('%Y-%m-%d')}, {describe()}; {args.preset} "
          f"on {args.sequence} ({w}x{h}), one stream at {args.fps:g} fps, {args.frames} frames, "
          f"{args.router} router, {args.path} path; CPU ms per frame\n")
    encs = list(columns)
    print("| stage | " + " | ".join(encs) + " |")
    print("| --- |" + " --- |" * len(encs))
    rows = [*STAGES, "worker, the rest", MAIN] + ([ROUTER] if args.router == "external" else [])
    for row in rows:
        print(f"| {row} | " + " | ".join(f"{columns[e][row]:.2f}" for e in encs) + " |")
    total = {e: sum(columns[e][r] for r in rows) for e in encs}
    print("| **service, all** | " + " | ".join(f"**{total[e]:.2f}**" for e in encs) + " |")
    print("| **overhead (all but track)** | " + " | ".join(
        f"**{total[e] - columns[e]['track']:.2f}**" for e in encs) + " |")
    print(f"| {QUEUE} | " + " | ".join(f"{columns[e][QUEUE]:.2f}" for e in encs) + " |")
    for key, label in (("decode", "back to back: decode"), ("track", "back to back: track"),
                       ("paced decode", f"paced at {args.fps:g} fps: decode"),
                       ("paced track", f"paced at {args.fps:g} fps: track")):
        print(f"| library alone, {label} | " + " | ".join(
            f"{alone[e][key]:.2f}" for e in encs) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

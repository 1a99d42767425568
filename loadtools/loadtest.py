"""``arcf-loadtest``: replay dataset sequences as concurrent drone streams against a service.

    arcf-loadtest --streams 4 --fps 10 --preset arcf-h --duration 20
    arcf-loadtest --spawn-service --sweep 1,2,4,8 --fps 30 --preset arcf-hc --out report

Each stream replays a real sequence (JPEG frames passed through as-is) at a fixed rate (or as
fast as possible with ``--fps 0``), with one or more tracking sessions started from the ground
truth's first box; stream starts are staggered. The run stops after ``--duration`` seconds or
``--frames`` frames per stream, whichever comes first.

Measured per stream and overall: end-to-end latency (capture timestamp to result received),
result rate, frames the service dropped (from the results' frame numbers), frames with no result
at all, and accuracy (precision@20 / AUC) through the service next to the same tracker run
offline on the same frames. The service's metrics are scraped before and after and compared with
what was observed.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shlex
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arcf.client.media.images import decode_compressed
from arcf.client.transport import ZENOH_SHORT_FLAGS
from arcf.eval import load_dataset, score_sequence
from arcf.service.scrape import delta, scrape

from .driver import Clip, Fleet, Pacing
from .ledger import Received, meets_capacity, percentiles
from .procs import ServiceProcess
from .system import CpuMeter


@dataclass
class StreamReport:
    stream: str
    sequence: str
    sessions: int
    frames_sent: int = 0
    results: int = 0
    dropped_by_service: int = 0
    missing: int = 0
    latency_ms: dict[str, float] = field(default_factory=dict)
    result_rate: float = 0.0
    precision20: float = float("nan")
    auc: float = float("nan")
    offline_precision20: float = float("nan")
    offline_auc: float = float("nan")


def time_breakdown(delta: dict[str, float]) -> dict[str, float]:
    """Mean milliseconds per frame spent decoding, tracking, and everywhere else (transport in,
    queueing, message decoding and result publishing), from the service's own histograms."""

    def mean(name: str) -> float:
        n = delta.get(f"{name}_count", 0.0)
        return 1e3 * delta.get(f"{name}_sum", 0.0) / n if n else float("nan")

    decode, track = mean("arcf_decode_seconds"), mean("arcf_track_seconds")
    e2e = mean("arcf_end_to_end_latency_seconds")
    frames = delta.get("arcf_decode_seconds_count", 0.0)
    per_frame = delta.get("arcf_track_seconds_count", 0.0) / frames if frames else float("nan")
    return {"decode_ms": decode, "track_ms": track, "sessions_per_frame": per_frame,
            "end_to_end_ms": e2e, "other_ms": e2e - decode - track * per_frame}


def _held_boxes(results: list[Received], n: int) -> np.ndarray:
    """One box per frame of the first ``n``, from a session's results: a frame without a
    result (dropped by the service) keeps the box before it, as a display would, and frames
    before the first result have none (scored as a miss)."""
    boxes = np.full((n, 4), np.nan)
    for r in results:
        if r.frame_seq < n:
            boxes[r.frame_seq] = r.result.box
    last = None
    for i in range(n):
        if np.isnan(boxes[i, 0]) and last is not None:
            boxes[i] = last
        last = boxes[i] if not np.isnan(boxes[i, 0]) else last
    return np.nan_to_num(boxes, nan=0.0)


def _first_pass_truth(clip: Clip, n: int) -> np.ndarray:
    assert clip.groundtruth is not None, "a scored clip plays forward"
    return clip.groundtruth[:n]


def _offline(preset: str, clip: Clip, n: int) -> tuple[float, float]:
    """The library alone, in this process, on the clip's first ``n`` JPEG frames: (P@20, AUC)."""

    import arcf

    frames = (decode_compressed(d) for d in clip.frames[:n])  # as a worker decodes them
    run = arcf.run_sequence(arcf.create_tracker(preset), frames, clip.box)
    sc = score_sequence(run.boxes, _first_pass_truth(clip, n))
    return sc.precision20, sc.auc


def _library_loop(preset: str,
                  items: list[tuple[tuple[float, float, float, float], list[bytes]]],
                  seconds: float, start: Any, out: Any) -> None:
    """One library process: decode + track the sequences in turn for ``seconds`` (spawned)."""
    import cv2

    import arcf

    cv2.setNumThreads(1)  # as in a service worker: one core per process
    tracker = arcf.create_tracker(preset)
    box, data = items[0]
    tracker.init(decode_compressed(data[0]), box)
    start.wait()  # all processes start timing together, after their imports and warm-up
    frames, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for box, data in items:
            decoded = (decode_compressed(d) for d in data)  # as a worker decodes them
            for _ in arcf.track_frames(tracker, decoded, box):
                frames += 1
                if time.perf_counter() - t0 >= seconds:
                    break
            else:
                continue
            break
    out.put(frames / (time.perf_counter() - t0))


def library_throughput(preset: str,
                       items: list[tuple[tuple[float, float, float, float], list[bytes]]],
                       processes: int = 1, seconds: float = 10.0) -> float:
    """Frames per second (decode + track, the work a worker does per frame) of ``processes``
    library processes running side by side on the same frames, with no service in the way.

    One process is the per-core yardstick of the issue; as many processes as workers is the
    ceiling the service could reach on this machine."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    start, out = ctx.Barrier(processes), ctx.Queue()
    procs = [ctx.Process(target=_library_loop, args=(preset, items, seconds, start, out),
                         daemon=True) for _ in range(processes)]
    for proc in procs:
        proc.start()
    try:
        return float(sum(out.get(timeout=seconds + 120) for _ in procs))
    finally:
        for proc in procs:
            proc.join(timeout=10)


def run_load(
    connect: list[str],
    sequences: list[Any],
    *,
    streams: int,
    sessions_per_stream: int = 1,
    preset: str = "arcf-h",
    fps: float = 10.0,
    duration: float = 20.0,
    max_frames: int = 0,
    window: int = 0,
    stagger: float = 0.2,
    aligned: bool = False,
    loop: bool = False,
    in_flight: int = 0,
    metrics_url: str | None = None,
    service_pid: int | None = None,
    prefix: str = "arcf/v1",
    progress: bool = True,
    offline: bool = True,
    reference_seconds: float = 10.0,
    reference_processes: int | None = None,
    cache: dict[Any, Any] | None = None,
    client: Any = None,
    encoding: str = "jpeg",
) -> dict[str, Any]:
    """Run one load level and return its report (a JSON-able dict).

    Stream k replays ``sequences[k mod len]`` (its first ``max_frames``, or ``window``,
    frames), paced by ``fps`` (0: as fast as possible), ``in_flight`` and ``aligned`` (see
    :class:`~arcf.loadtools.driver.Pacing`); stream starts are ``stagger`` s apart.

    With ``loop`` a stream replays its sequence again from the start when it runs out (the
    sessions are re-initialised on the ground truth's first box at each wrap), so a run can last
    longer than the sequence; accuracy is scored on the first pass. ``window`` replays only the
    sequence's first frames (looped), so that the service and the library reference below
    track exactly the same frames whatever their speed: a target's size, and with it the cost
    of a frame, changes along a sequence. With ``in_flight`` > 0 each stream is a closed loop,
    so several such streams per worker keep every worker busy without a single drop, which is
    how the service's saturation throughput is measured. ``encoding`` ``jpeg-sdk`` sends each
    clip's pictures as the client SDK encodes them (``Clip.as_sent``: restart intervals a
    worker decodes around the target only); ``h264`` / ``h265`` as a camera's video
    (``Clip.as_video``, at ``fps``) instead of its JPEG files, and the library reference then
    is not run (``reference_seconds`` must be 0).

    The library's own throughput on the same frames is measured for ``reference_seconds`` (0
    skips it), half before the load and half after: one process, and ``reference_processes``
    side by side (default: one per CPU, like the service's workers). ``cache`` keeps the offline
    accuracy runs across the levels of a sweep. ``client`` replaces the client made from
    ``connect`` and ``prefix`` (a test's stand-in for the service, for one).
    """
    clips = []
    for seq in sequences[: min(streams, len(sequences))]:
        n = min(len(seq), max_frames) if max_frames else len(seq)
        clip = Clip.of(seq, limit=min(n, window) if window else n)
        clips.append(clip if encoding == "jpeg" else clip.as_sent() if encoding == "jpeg-sdk"
                     else clip.as_video(encoding, int(fps or 30)))
    if encoding not in ("jpeg", "jpeg-sdk") and reference_seconds > 0:
        raise ValueError("the library reference decodes JPEG frames: reference_seconds=0 "
                         "for video")
    cache = cache if cache is not None else {}
    workers = reference_processes or os.cpu_count() or 1
    reference: dict[str, Any] = {"library_fps": float("nan"),
                                 "library_parallel_fps": float("nan"),
                                 "library_processes": workers, "library_fps_runs": [],
                                 "library_parallel_fps_runs": []}
    items = [(clip.box, list(clip.frames)) for clip in clips]

    def measure_reference() -> None:
        """Half the reference time before the load and half after, so that the drift of a
        shared machine during the run weighs on both sides of the comparison alike."""
        half = reference_seconds / 2
        reference["library_fps_runs"].append(library_throughput(preset, items, 1, half))
        reference["library_parallel_fps_runs"].append(
            library_throughput(preset, items, workers, half))
        reference["library_fps"] = float(np.mean(reference["library_fps_runs"]))
        reference["library_parallel_fps"] = float(np.mean(reference["library_parallel_fps_runs"]))

    if reference_seconds > 0:
        measure_reference()

    before = scrape(metrics_url)
    pacing = Pacing(fps=fps, in_flight=in_flight, aligned=aligned)
    with contextlib.ExitStack() as stack:
        if client is None:
            from arcf.client import TrackingClient

            client = stack.enter_context(TrackingClient(connect=connect, prefix=prefix))
        fleet = stack.enter_context(Fleet(client, clips, preset=preset, pacing=pacing,
                                          prefix="load"))
        # every session first; then all streams start together, ``stagger`` apart
        for k in range(streams):
            # stream k's frame count: its clip, or (looping) up to max_frames or the duration
            count = (max_frames or None) if loop else len(clips[k % len(clips)])
            fleet.add(1, sessions=sessions_per_stream, frames=count, reinit_on_wrap=loop,
                      delay=k * stagger, hold=True)
        started = list(fleet.live)
        cpu = CpuMeter(service_pid)
        start = fleet.release()
        stop_at = start + duration + stagger * streams
        while any(st.publishing() for st in started) and time.monotonic() < stop_at:
            time.sleep(min(1.0, max(0.0, stop_at - time.monotonic())))
            if progress:
                recent = [r for st in started for r in st.record.received[-50:]]
                p99 = percentiles([r.latency_s for r in recent])["p99"]
                print(f"\r{streams} streams: {sum(st.sent for st in started)} frames sent, "
                      f"{sum(len(st.record.received) for st in started)} results, "
                      f"p99 {p99:.0f} ms, {time.monotonic() - start:.0f} s", end="",
                      file=sys.stderr, flush=True)
        fleet.pause()
        fleet.settle(timeout=10)  # the tail: every session answers its stream's last frame
        elapsed = time.monotonic() - start
        cpu_use = cpu.read()
    if progress:
        print(file=sys.stderr)
    time.sleep(0.5)
    after = scrape(metrics_url)
    if reference_seconds > 0:
        measure_reference()

    reports, all_lat = [], []
    for st in started:
        rs = st.record.received
        rep = StreamReport(st.name, st.clip.name, sessions_per_stream, frames_sent=st.sent,
                           results=len(rs))
        lat = [r.latency_s for r in rs]
        all_lat += lat
        rep.latency_ms = percentiles(lat)
        rep.result_rate = len(rs) / elapsed if elapsed > 0 else 0.0
        counts = st.record.accounting()
        rep.dropped_by_service = counts["skipped_at_start"] + counts["dropped"]
        # frames that got neither a result nor a place in a later result's ``dropped``
        rep.missing = st.sent * len(st.sessions) - rep.results - rep.dropped_by_service
        first_pass = min(st.sent, len(st.clip))
        p20, aucs = [], []
        for sid in st.sessions:
            session_results = st.record.results_of(sid)
            if not session_results:
                continue
            sc = score_sequence(_held_boxes(session_results, first_pass),
                                _first_pass_truth(st.clip, first_pass))
            p20.append(sc.precision20)
            aucs.append(sc.auc)
        rep.precision20 = float(np.mean(p20)) if p20 else float("nan")
        rep.auc = float(np.mean(aucs)) if aucs else float("nan")
        if offline and first_pass:
            key = ("offline", preset, st.clip.name, first_pass)
            if key not in cache:
                cache[key] = _offline(preset, st.clip, first_pass)
            rep.offline_precision20, rep.offline_auc = cache[key]
        reports.append(rep)

    total_sent = sum(r.frames_sent for r in reports)
    total_results = sum(r.results for r in reports)
    metrics_delta = delta(before, after)
    result_rate = total_results / elapsed if elapsed > 0 else 0.0
    # throughput in the steady state: every stream sending (plus a second), none finished yet
    sending = [st.record.sent for st in started if st.sent]
    t_a = max(sent[0][1] for sent in sending) + 1.0 if sending else 0.0
    t_b = min(sent[-1][1] for sent in sending) if sending else 0.0
    if t_b - t_a >= 2.0:
        processed_rate = fleet.ledger.window(t_a, t_b)["processed_fps"]
    else:
        processed_rate = result_rate / sessions_per_stream
    cpus = cpu_use["cpus"]
    single = reference["library_fps"]
    return {
        "streams": streams, "sessions_per_stream": sessions_per_stream, "preset": preset,
        "fps": fps, "loop": loop, "elapsed_s": elapsed,
        "sequences": sorted({st.clip.name for st in started}),
        "frames_sent": total_sent, "results": total_results,
        "dropped_by_service": sum(r.dropped_by_service for r in reports),
        "missing": sum(r.missing for r in reports),
        "latency_ms": percentiles(all_lat),
        "result_rate": result_rate,
        "processed_fps": processed_rate,
        **reference,
        # frames/s through the service per CPU, as a share of one library process; meaningful
        # at saturation (offered load above what the service can track)
        "efficiency": processed_rate / (single * cpus),
        # the same, counting only the CPUs the load generator left to the service
        "efficiency_net": processed_rate / (single * max(cpus - cpu_use["generator_cores"], 1e-9)),
        # against library processes running side by side: the ceiling on this machine
        "efficiency_parallel": processed_rate / reference["library_parallel_fps"],
        "cpu": cpu_use,
        "breakdown": time_breakdown(metrics_delta) if metrics_url else {},
        "metrics_delta": metrics_delta,
        "metrics_agree": (not metrics_url) or (
            metrics_delta.get("arcf_results_published_total", -1) == total_results),
        "per_stream": [asdict(r) for r in reports],
    }


def passes(report: dict[str, Any], p99_ms: float = 100.0) -> bool:
    """``meets_capacity`` of a ``run_load`` report."""
    return meets_capacity(report["results"], report["dropped_by_service"] + report["missing"],
                          report["latency_ms"]["p99"], p99_ms)


def markdown(reports: list[dict[str, Any]]) -> str:
    lines = ["| streams | preset | fps/stream | frames sent | results | dropped | missing | "
             "p50 / p95 / p99 / max latency (ms) | service fps | library fps: 1 / N processes "
             "| service / (N x 1 process) (net of generator) | service / N processes | "
             "CPU cores: generator / service / machine | metrics agree |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- "
             "| --- |"]
    for r in reports:
        lat, cpu = r["latency_ms"], r.get("cpu", {})
        lines.append(
            f"| {r['streams']} | {r['preset']} | {r['fps']:g} | {r['frames_sent']} | "
            f"{r['results']} | {r['dropped_by_service']} | {r['missing']} | {lat['p50']:.0f} / "
            f"{lat['p95']:.0f} / {lat['p99']:.0f} / {lat['max']:.0f} | "
            f"{r['processed_fps']:.1f} | {r['library_fps']:.1f} / "
            f"{r['library_parallel_fps']:.1f} (N={r['library_processes']}) | "
            f"{100 * r['efficiency']:.0f} % ({100 * r['efficiency_net']:.0f} %) | "
            f"{100 * r['efficiency_parallel']:.0f} % | "
            f"{cpu.get('generator_cores', float('nan')):.2f} / "
            f"{cpu.get('service_cores', float('nan')):.2f} / "
            f"{cpu.get('machine_cores', float('nan')):.2f} | "
            f"{'yes' if r['metrics_agree'] else 'NO'} |")
    if any(r.get("breakdown") for r in reports):
        lines += ["", "Where a frame's time goes, from the service's histograms (mean ms):", "",
                  "| streams | decode | track (per session) | other: transport, queueing, "
                  "messages | end to end (to publish) |",
                  "| --- | --- | --- | --- | --- |"]
        for r in reports:
            b = r.get("breakdown") or {}
            if b:
                lines.append(f"| {r['streams']} | {b['decode_ms']:.1f} | {b['track_ms']:.1f} | "
                             f"{b['other_ms']:.1f} | {b['end_to_end_ms']:.1f} |")
    lines += ["", "| stream | sequence | sent | results | dropped | "
              "P@20 / AUC through the service | offline |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in reports:
        for s in r["per_stream"]:
            lines.append(f"| {s['stream']} ({r['streams']} streams) | {s['sequence']} | "
                         f"{s['frames_sent']} | {s['results']} | {s['dropped_by_service']} | "
                         f"{s['precision20']:.3f} / {s['auc']:.3f} | "
                         f"{s['offline_precision20']:.3f} / {s['offline_auc']:.3f} |")
    return "\n".join(lines) + "\n"


def plot_sweep(reports: list[dict[str, Any]], path: Path) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 3.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 2, 1)
    n = [r["streams"] for r in reports]
    for key in ("p50", "p95", "p99"):
        ax.plot(n, [r["latency_ms"][key] for r in reports], marker="o", label=key)
    ax.axhline(100, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("concurrent streams")
    ax.set_ylabel("end-to-end latency (ms)")
    ax.legend()
    ax.grid(alpha=0.3)
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.plot(n, [r["result_rate"] for r in reports], marker="o", label="results/s")
    ax2.plot(n, [r["streams"] * r["fps"] * r["sessions_per_stream"] for r in reports], ls="--",
             color="grey", label="offered")
    ax2.set_xlabel("concurrent streams")
    ax2.set_ylabel("results per second")
    ax2.legend()
    ax2.grid(alpha=0.3)
    fig.suptitle(f"{reports[0]['preset']}, {reports[0]['fps']:g} fps per stream")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="arcf-loadtest", description=__doc__.splitlines()[0])
    ap.add_argument(ZENOH_SHORT_FLAGS["connect"], "--connect", action="append",
                    metavar="ENDPOINT", help="the service's Zenoh endpoint(s) (repeatable)")
    ap.add_argument("--spawn-service", action="store_true",
                    help="start an arcf-service on a free loopback port for the run")
    ap.add_argument("--service-args", default="", metavar="ARGS",
                    help="more arguments for the spawned service, e.g. "
                         "--service-args='--max-stream-fps 10000' for closed loops that outrun "
                         "the per-stream rate limit")
    ap.add_argument("--metrics-url", help="the service's /metrics URL (scraped before/after)")
    ap.add_argument("--service-pid", type=int,
                    help="pid of the service's main process, to measure its CPU use")
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--sequences", default="", help="comma-separated (default: all local)")
    ap.add_argument("--streams", type=int, default=2)
    ap.add_argument("--sweep", default="", help="e.g. 1,2,4,8: one run per stream count")
    ap.add_argument("--capacity", action="store_true",
                    help="add streams one at a time until the criterion fails; report the "
                         "largest count that passed")
    ap.add_argument("--max-streams", type=int, default=16, help="bound for --capacity")
    ap.add_argument("--p99-ms", type=float, default=100.0,
                    help="capacity criterion: p99 end-to-end latency bound (and no drops)")
    ap.add_argument("--sessions-per-stream", type=int, default=1)
    ap.add_argument("--preset", default="arcf-h")
    ap.add_argument("--fps", type=float, default=10.0, help="per stream; 0 = as fast as possible")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds per run (bound)")
    ap.add_argument("--frames", type=int, default=0, help="frames per stream (bound)")
    ap.add_argument("--window", type=int, default=0,
                    help="replay only the first N frames of each sequence (with --loop)")
    ap.add_argument("--loop", action="store_true",
                    help="replay sequences again when they end (until --duration/--frames)")
    ap.add_argument("--in-flight", type=int, default=0,
                    help="closed loop: at most this many unanswered frames per stream "
                         "(with --fps 0: saturation without drops)")
    ap.add_argument("--stagger", type=float, default=0.2, help="seconds between stream starts")
    ap.add_argument("--aligned", action="store_true",
                    help="every stream's frames at the same instants (a synchronised fleet: "
                         "the worst case); default: phases spread over the frame period")
    ap.add_argument("--out", default="loadtest", help="report basename (.json, .md, .png)")
    ap.add_argument("--no-offline", action="store_true",
                    help="skip the offline accuracy comparison")
    ap.add_argument("--reference-seconds", type=float, default=10.0,
                    help="how long to measure the library's own throughput (0: skip)")
    args = ap.parse_args(argv)

    seqs = load_dataset(args.dataset)
    if args.sequences:
        wanted = args.sequences.split(",")
        seqs = sorted((s for s in seqs if s.name in wanted), key=lambda s: wanted.index(s.name))
    if not seqs:
        raise SystemExit("arcf-loadtest: no sequences")
    if args.capacity:
        levels = list(range(1, args.max_streams + 1))
    else:
        levels = [int(x) for x in args.sweep.split(",") if x] or [args.streams]
    proc = None
    connect, metrics_url = args.connect or ["tcp/127.0.0.1:7447"], args.metrics_url
    service_pid = args.service_pid
    if args.spawn_service:
        proc = ServiceProcess(*shlex.split(args.service_args), workers=os.cpu_count() or 1,
                              quiet=False)
        connect, metrics_url, service_pid = [proc.endpoint], proc.metrics_url, proc.pid
        print(f"arcf-service started on {proc.endpoint}", file=sys.stderr)
    reports: list[dict[str, Any]] = []
    cache: dict[Any, Any] = {}
    try:
        for n in levels:
            report = run_load(connect, seqs, streams=n,
                              sessions_per_stream=args.sessions_per_stream, preset=args.preset,
                              fps=args.fps, duration=args.duration, max_frames=args.frames,
                              window=args.window,
                              stagger=args.stagger, aligned=args.aligned, loop=args.loop,
                              in_flight=args.in_flight,
                              metrics_url=metrics_url,
                              service_pid=service_pid, offline=not args.no_offline,
                              reference_seconds=args.reference_seconds, cache=cache)
            report["passes"] = passes(report, args.p99_ms)
            reports.append(report)
            if args.capacity and not report["passes"]:
                break
    finally:
        if proc is not None:
            proc.stop()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(reports, indent=1, default=float) + "\n")
    md = markdown(reports)
    if args.capacity:
        ok = [r["streams"] for r in reports if r["passes"]]
        md = (f"Capacity ({args.preset}, {args.fps:g} fps per stream, p99 < {args.p99_ms:g} ms, "
              f"no drops): {max(ok) if ok else 0} streams\n\n" + md)
    out.with_suffix(".md").write_text(md)
    if len(reports) > 1:
        plot_sweep(reports, out.with_suffix(".png"))
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())

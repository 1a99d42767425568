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
import json
import re
import subprocess
import sys
import threading
import time
import urllib.request
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


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
    #: The library alone in this process on the same frames: decode + track, frames per second.
    library_fps: float = float("nan")


def _percentiles(values: list[float]) -> dict[str, float]:
    if not values:
        return {k: float("nan") for k in ("p50", "p95", "p99", "max")}
    a = np.asarray(values) * 1e3
    return {"p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95)),
            "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def scrape(url: str | None) -> dict[str, float]:
    """Counter totals from a Prometheus endpoint (summed over label values)."""
    if not url:
        return {}
    text = urllib.request.urlopen(url, timeout=5).read().decode()
    out: dict[str, float] = {}
    for name, value in re.findall(r"^(arcf_[a-z_]+?)(?:\{[^}]*\})?\s+([0-9.eE+-]+)$", text,
                                  flags=re.M):
        out[name] = out.get(name, 0.0) + float(value)
    return out


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
    stagger: float = 0.2,
    metrics_url: str | None = None,
    prefix: str = "arcf/v1",
    progress: bool = True,
    offline: bool = True,
) -> dict[str, Any]:
    """Run one load level and return its report (a JSON-able dict)."""
    import arcf
    from arcf.eval import score_sequence

    from .client import TrackingClient

    before = scrape(metrics_url)
    results: dict[str, list[tuple[Any, int]]] = {}
    sent: dict[str, int] = {}
    lock = threading.Lock()
    stop_at = time.monotonic() + duration + stagger * streams
    plan = []
    for k in range(streams):
        seq = sequences[k % len(sequences)]
        n = len(seq) if not max_frames else min(len(seq), max_frames)
        plan.append((f"load-{k}-{seq.name}", seq, [p.read_bytes() for p in seq.frames[:n]]))

    with TrackingClient(connect=connect, prefix=prefix) as client:
        subs, acks = [], []
        for name, seq, _ in plan:
            results[name] = []
            sent[name] = 0

            def on_result(r: Any, name: str = name) -> None:
                with lock:
                    results[name].append((r, time.time_ns()))

            subs.append(client.results(name, callback=on_result))
            for _ in range(sessions_per_stream):
                acks.append(client.start(name, seq.init_box, preset=preset, frame_seq=0))

        def publisher(k: int) -> None:
            name, _seq, data = plan[k]
            time.sleep(k * stagger)
            t0 = time.monotonic()
            for i, d in enumerate(data):
                if time.monotonic() > stop_at:
                    break
                client.publish_frame(name, data=d, seq=i)
                sent[name] = i + 1
                if fps > 0:
                    time.sleep(max(0.0, t0 + (i + 1) / fps - time.monotonic()))

        threads = [threading.Thread(target=publisher, args=(k,), daemon=True)
                   for k in range(streams)]
        start = time.monotonic()
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            time.sleep(1.0)
            if progress:
                with lock:
                    n_res = sum(len(v) for v in results.values())
                    lat = [(rcv - r.capture_ts_ns) / 1e9 for v in results.values()
                           for r, rcv in v[-50:]]
                p99 = np.percentile(lat, 99) * 1e3 if lat else float("nan")
                print(f"\r{streams} streams: {sum(sent.values())} frames sent, {n_res} results, "
                      f"p99 {p99:.0f} ms, {time.monotonic() - start:.0f} s", end="",
                      file=sys.stderr, flush=True)
        # the tail: wait until every session answered its stream's last frame (or give up)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            with lock:
                done = all(
                    sum(1 for r, _ in results[name] if r.frame_seq == sent[name] - 1)
                    >= sessions_per_stream for name, _, _ in plan if sent[name])
            if done:
                break
            time.sleep(0.05)
        elapsed = time.monotonic() - start
        for ack in acks:
            client.stop(ack.session_id)
        for s in subs:
            s.close()
        if progress:
            print(file=sys.stderr)
    time.sleep(0.5)
    after = scrape(metrics_url)

    reports, all_lat = [], []
    for name, seq, data in plan:
        rs = results[name]
        by_session: dict[str, list[Any]] = {}
        for r, rcv in rs:
            by_session.setdefault(r.session_id, []).append((r, rcv))
        rep = StreamReport(name, seq.name, sessions_per_stream, frames_sent=sent[name],
                           results=len(rs))
        lat = [(rcv - r.capture_ts_ns) / 1e9 for r, rcv in rs]
        all_lat += lat
        rep.latency_ms = _percentiles(lat)
        rep.result_rate = len(rs) / elapsed if elapsed > 0 else 0.0
        dropped = missing = 0
        p20, aucs = [], []
        for session_results in by_session.values():
            session_results.sort(key=lambda x: x[0].frame_seq)
            first = session_results[0][0].frame_seq
            d = first + sum(r.dropped for r, _ in session_results[1:])
            dropped += d
            missing += sent[name] - len(session_results) - d
            n = sent[name]
            boxes = np.full((n, 4), np.nan)
            last = None
            for r, _ in session_results:  # a dropped frame keeps the previous box
                boxes[r.frame_seq] = r.box
            for i in range(n):
                if np.isnan(boxes[i, 0]) and last is not None:
                    boxes[i] = last
                last = boxes[i] if not np.isnan(boxes[i, 0]) else last
            sc = score_sequence(np.nan_to_num(boxes, nan=0.0), seq.groundtruth[:n])
            p20.append(sc.precision20)
            aucs.append(sc.auc)
        # a session that produced no result at all is missing every frame
        missing += (sessions_per_stream - len(by_session)) * sent[name]
        rep.dropped_by_service, rep.missing = dropped, missing
        rep.precision20 = float(np.mean(p20)) if p20 else float("nan")
        rep.auc = float(np.mean(aucs)) if aucs else float("nan")
        if offline and sent[name]:
            import cv2

            t = arcf.create_tracker(preset)
            t0 = time.perf_counter()
            ob = []
            for i, d in enumerate(data[: sent[name]]):
                frame = cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_UNCHANGED)
                ob.append((t.init(frame, seq.init_box) if i == 0 else t.update(frame)).box)
            rep.library_fps = sent[name] / (time.perf_counter() - t0)
            osc = score_sequence(np.array(ob), seq.groundtruth[: sent[name]])
            rep.offline_precision20, rep.offline_auc = osc.precision20, osc.auc
        reports.append(rep)

    total_sent = sum(r.frames_sent for r in reports)
    total_results = sum(r.results for r in reports)
    metrics_delta = {k: after.get(k, 0.0) - before.get(k, 0.0) for k in after}
    return {
        "streams": streams, "sessions_per_stream": sessions_per_stream, "preset": preset,
        "fps": fps, "elapsed_s": elapsed,
        "frames_sent": total_sent, "results": total_results,
        "dropped_by_service": sum(r.dropped_by_service for r in reports),
        "missing": sum(r.missing for r in reports),
        "latency_ms": _percentiles(all_lat),
        "result_rate": total_results / elapsed if elapsed > 0 else 0.0,
        # one library process on the same frames (decode + track), frame-weighted over streams
        "library_fps": (sum(r.frames_sent for r in reports if np.isfinite(r.library_fps)) /
                        sum(r.frames_sent / r.library_fps for r in reports
                            if np.isfinite(r.library_fps) and r.library_fps > 0)
                        if any(np.isfinite(r.library_fps) for r in reports) else float("nan")),
        "metrics_delta": metrics_delta,
        "metrics_agree": (not metrics_url) or (
            metrics_delta.get("arcf_results_published_total", -1) == total_results),
        "per_stream": [asdict(r) for r in reports],
    }


def markdown(reports: list[dict[str, Any]]) -> str:
    lines = ["| streams | preset | fps/stream | frames sent | results | dropped | missing | "
             "p50 / p95 / p99 / max latency (ms) | results/s | library alone, fps | "
             "metrics agree |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in reports:
        lat = r["latency_ms"]
        lines.append(
            f"| {r['streams']} | {r['preset']} | {r['fps']:g} | {r['frames_sent']} | "
            f"{r['results']} | {r['dropped_by_service']} | {r['missing']} | {lat['p50']:.0f} / "
            f"{lat['p95']:.0f} / {lat['p99']:.0f} / {lat['max']:.0f} | {r['result_rate']:.1f} | "
            f"{r['library_fps']:.1f} | {'yes' if r['metrics_agree'] else 'NO'} |")
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
    ap.add_argument("--connect", action="append", help="service endpoint(s)")
    ap.add_argument("--spawn-service", action="store_true",
                    help="start an arcf-service on a free loopback port for the run")
    ap.add_argument("--metrics-url", help="the service's /metrics URL (scraped before/after)")
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--sequences", default="", help="comma-separated (default: all local)")
    ap.add_argument("--streams", type=int, default=2)
    ap.add_argument("--sweep", default="", help="e.g. 1,2,4,8: one run per stream count")
    ap.add_argument("--sessions-per-stream", type=int, default=1)
    ap.add_argument("--preset", default="arcf-h")
    ap.add_argument("--fps", type=float, default=10.0, help="per stream; 0 = as fast as possible")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds per run (bound)")
    ap.add_argument("--frames", type=int, default=0, help="frames per stream (bound)")
    ap.add_argument("--stagger", type=float, default=0.2, help="seconds between stream starts")
    ap.add_argument("--out", default="loadtest", help="report basename (.json, .md, .png)")
    ap.add_argument("--no-offline", action="store_true", help="skip the offline comparison")
    args = ap.parse_args(argv)

    from arcf.eval import load_dataset

    seqs = load_dataset(args.dataset)
    if args.sequences:
        wanted = args.sequences.split(",")
        seqs = [s for s in seqs if s.name in wanted]
    if not seqs:
        raise SystemExit("arcf-loadtest: no sequences")
    levels = [int(x) for x in args.sweep.split(",") if x] or [args.streams]
    proc = None
    connect, metrics_url = args.connect or ["tcp/127.0.0.1:7447"], args.metrics_url
    if args.spawn_service:
        import socket

        def free() -> int:
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                return s.getsockname()[1]

        port, mport = free(), free()
        connect = [f"tcp/127.0.0.1:{port}"]
        metrics_url = f"http://127.0.0.1:{mport}/metrics"
        proc = subprocess.Popen([sys.executable, "-m", "service.app", "--listen", connect[0],
                                 "--metrics-port", str(mport)], stdout=subprocess.PIPE, text=True)
        assert proc.stdout is not None
        print(proc.stdout.readline().strip(), file=sys.stderr)
    try:
        reports = [run_load(connect, seqs, streams=n, sessions_per_stream=args.sessions_per_stream,
                            preset=args.preset, fps=args.fps, duration=args.duration,
                            max_frames=args.frames, stagger=args.stagger,
                            metrics_url=metrics_url, offline=not args.no_offline)
                   for n in levels]
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=30)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(reports, indent=1, default=float) + "\n")
    md = markdown(reports)
    out.with_suffix(".md").write_text(md)
    if len(reports) > 1:
        plot_sweep(reports, out.with_suffix(".png"))
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())

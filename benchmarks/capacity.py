"""Capacity of one arcf-service on this machine: how many real-time 1280x720 streams it sustains,
and its throughput at saturation next to the library's own.

Two parts, one spawned service (one worker per CPU) for all of it:

1. **Capacity**: for each preset, frame rate and sequence, streams are added one at a time (all
   replaying that sequence, looped, paced at the frame rate) until the criterion fails: p99
   end-to-end latency under 100 ms and not a single frame dropped or missing. The capacity is
   the last stream count that passed. Per sequence, because the cost of a frame depends on the
   target's size far more than on the image's.
2. **Saturation**: closed-loop streams (one frame in flight each, two per worker) keep every
   worker busy without a drop, and the service's frames per second are set against the library
   decoding and tracking the same frames, in one process and in one process per CPU, measured
   just before and after (the service's efficiency). The service's histograms give the time
   breakdown (decode, track, the rest) and /proc the CPU use of generator and service.

    python benchmarks/capacity.py                      # everything, ~40 min on 2 cores
    python benchmarks/capacity.py --presets arcf-hc --fps 10 --sequences wakeboard7

Writes ``capacity.json`` and prints Markdown tables (for docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from arcf.client import TrackingClient
from arcf.loadtools.loadtest import passes, run_load
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.system import machine
from arcf.loadtools.waiting import wait_for_peers


def image_size(seq: Any) -> list[int]:

    h, w = seq.read_frame(0).shape[:2]
    return [w, h]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="arcf-h,arcf-hc")
    ap.add_argument("--fps", default="10,30")
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--sequences", default="", help="comma-separated (default: all local)")
    ap.add_argument("--encodings", default="jpeg",
                    help="comma-separated: jpeg (the datasets' files) and / or h264 (the "
                         "same frames as a camera's video, decoding included); capacity only")
    ap.add_argument("--duration", type=float, default=15.0, help="seconds per load level")
    ap.add_argument("--max-streams", type=int, default=10)
    ap.add_argument("--p99-ms", type=float, default=100.0)
    ap.add_argument("--saturation-sequences", default="boat1,truck4_1,wakeboard7")
    ap.add_argument("--saturation-seconds", type=float, default=30.0)
    ap.add_argument("--saturation-window", type=int, default=60,
                    help="frames of each sequence replayed (looped) at saturation, by the "
                         "service and by the library reference alike")
    ap.add_argument("--reference-seconds", type=float, default=30.0)
    ap.add_argument("--workers", type=int, default=0,
                    help="the service's worker processes (default: one per CPU)")
    ap.add_argument("--spare-workers", type=int, default=0,
                    help="the service's spare workers (taking streams off an overloaded one)")
    ap.add_argument("--path", choices=("router", "direct"), default="router",
                    help="frames through the router, or straight to the workers (peer "
                    "stations, --worker-listen)")
    ap.add_argument("--skip-capacity", action="store_true")
    ap.add_argument("--skip-saturation", action="store_true")
    ap.add_argument("--out", default="capacity.json")
    args = ap.parse_args()

    from arcf.eval import load_dataset

    seqs = load_dataset(args.dataset)
    if args.sequences:
        seqs = [s for s in seqs if s.name in args.sequences.split(",")]
    presets = args.presets.split(",")
    rates = [float(x) for x in args.fps.split(",")]
    ncpu = os.cpu_count() or 1
    # closed-loop streams at saturation run faster than the per-stream rate limit (60 fps by
    # default: a station flooding the others): lifted here, where throughput is the question
    direct = args.path == "direct"
    svc = ServiceProcess("--max-stream-fps", "10000",
                         "--spare-workers", str(args.spare_workers),
                         *(("--worker-listen", "tcp/127.0.0.1:0") if direct else ()),
                         workers=args.workers or ncpu, quiet=False)
    proc, endpoint, metrics_url = svc.proc, svc.endpoint, svc.metrics_url
    out: dict[str, Any] = {"machine": machine(), "workers": args.workers or ncpu,
                           "spare_workers": args.spare_workers, "path": args.path,
                           "capacity": [], "saturation": []}

    @contextlib.contextmanager
    def station() -> Iterator[Any]:
        """A level's station: the load tool's own (None), or a peer linked to every worker."""
        if not direct:
            yield None
            return
        with TrackingClient(connect=[endpoint], mode="peer") as client:
            wait_for_peers(client.session, out["workers"] + args.spare_workers)
            yield client

    t_start = time.monotonic()
    try:
        if not args.skip_capacity:
            for encoding, preset, fps, seq in itertools.product(
                    args.encodings.split(","), presets, rates, seqs):
                levels = []
                for n in range(1, args.max_streams + 1):
                    with station() as client:
                        r = run_load([endpoint], [seq], streams=n, preset=preset, fps=fps,
                                     duration=args.duration, loop=True,
                                     metrics_url=metrics_url, service_pid=proc.pid,
                                     offline=False, reference_seconds=0, progress=False,
                                     encoding=encoding, client=client)
                    r["passes"] = passes(r, args.p99_ms)
                    keep = ("sequence", "frames_sent", "results", "dropped_by_service",
                            "latency_ms")
                    r["per_stream"] = [{k: s[k] for k in keep} for s in r["per_stream"]]
                    levels.append(r)
                    print(f"{encoding} {preset} {fps:g} fps {seq.name}: {n} streams, "
                          f"p99 {r['latency_ms']['p99']:.0f} ms, "
                          f"dropped {r['dropped_by_service']}, "
                          f"{'pass' if r['passes'] else 'FAIL'}", file=sys.stderr)
                    if not r["passes"]:
                        break
                ok = [r["streams"] for r in levels if r["passes"]]
                out["capacity"].append({"encoding": encoding, "preset": preset,
                                        "fps": fps,
                                        "sequence": seq.name,
                                        "size": image_size(seq),
                                        "capacity": max(ok) if ok else 0,
                                        "levels": levels})
                Path(args.out).write_text(json.dumps(out, indent=1, default=float))
        if not args.skip_saturation:
            sat = [s for s in seqs if s.name in args.saturation_sequences.split(",")]
            for preset in presets:
                for seq in sat:
                    with station() as client:
                        r = run_load([endpoint], [seq], streams=2 * ncpu, preset=preset,
                                     fps=0, in_flight=1, duration=args.saturation_seconds,
                                     loop=True, window=args.saturation_window,
                                     metrics_url=metrics_url, service_pid=proc.pid,
                                     offline=False, reference_seconds=args.reference_seconds,
                                     progress=False, client=client)
                    r.pop("per_stream")
                    out["saturation"].append(r)
                    print(f"{preset} saturation {seq.name}: {r['processed_fps']:.1f} fps, "
                          f"library {r['library_fps']:.1f} x {ncpu}", file=sys.stderr)
                    Path(args.out).write_text(json.dumps(out, indent=1, default=float))
    finally:
        svc.stop()
    out["minutes"] = (time.monotonic() - t_start) / 60
    Path(args.out).write_text(json.dumps(out, indent=1, default=float))
    print(markdown(out))
    return 0


def markdown(out: dict[str, Any]) -> str:
    m = out["machine"]
    workers = out.get("workers", m["nproc"])
    software = f", {m['software']}" if m.get("software") else ""
    path = out.get("path", "router")
    spares = out.get("spare_workers", 0)
    lines = [f"Machine: nproc {m['nproc']}, {m['cpu']}{software}; {workers} workers"
             f"{f' and {spares} spare' if spares else ''}; frames through the "
             f"{'router' if path == 'router' else 'direct path'}.", ""]
    if out["capacity"]:
        cols = list(dict.fromkeys((c.get("encoding", "jpeg"), c["preset"], c["fps"])
                                  for c in out["capacity"]))
        seqs = list(dict.fromkeys(c["sequence"] for c in out["capacity"]))
        head = " | ".join(f"{p}, {f:g} fps, {e.upper()}" for e, p, f in cols)
        lines += [f"| sequence | {head} |", "| --- |" + " --- |" * len(cols)]
        by = {(c.get("encoding", "jpeg"), c["preset"], c["fps"], c["sequence"]): c
              for c in out["capacity"]}
        for s in seqs:
            cells = []
            for col in cols:
                c = by.get((*col, s))
                if c is None:
                    cells.append("")
                    continue
                best = next((r for r in c["levels"] if r["streams"] == c["capacity"]), None)
                p99 = f" (p99 {best['latency_ms']['p99']:.0f} ms)" if best else ""
                cells.append(f"{c['capacity']}{p99}")
            lines.append(f"| {s} | " + " | ".join(cells) + " |")
        lines += ["", "| encoding | preset | fps | sequence | streams | dropped | p50 / p99 (ms) "
                  "| generator / service CPU (cores) | pass |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for c in out["capacity"]:
            for r in c["levels"]:
                lat, cpu = r["latency_ms"], r["cpu"]
                lines.append(f"| {c.get('encoding', 'jpeg')} | {c['preset']} | {c['fps']:g} "
                             f"| {c['sequence']} | {r['streams']} "
                             f"| {r['dropped_by_service']} | {lat['p50']:.0f} / {lat['p99']:.0f} "
                             f"| {cpu['generator_cores']:.2f} / {cpu.get('service_cores', 0):.2f} "
                             f"| {'yes' if r['passes'] else 'no'} |")
    if out["saturation"]:
        lines += ["", "| preset | sequence | service fps | library fps, 1 process (runs) | "
                  "library fps, N processes | service / (N x 1 process) | net of generator | "
                  "service / N processes | decode / track / other (ms) | CPU: generator / "
                  "service |", "| --- " * 10 + "|"]
        for r in out["saturation"]:
            b, cpu = r["breakdown"], r["cpu"]
            runs = ", ".join(f"{x:.1f}" for x in r["library_fps_runs"])
            lines.append(
                f"| {r['preset']} | {r['sequences'][0]} | {r['processed_fps']:.1f} | "
                f"{r['library_fps']:.1f} ({runs}) | {r['library_parallel_fps']:.1f} "
                f"(N={r['library_processes']}) | {100 * r['efficiency']:.0f} % | "
                f"{100 * r['efficiency_net']:.0f} % | {100 * r['efficiency_parallel']:.0f} % | "
                f"{b['decode_ms']:.1f} / {b['track_ms']:.1f} / {b['other_ms']:.1f} | "
                f"{cpu['generator_cores']:.2f} / {cpu.get('service_cores', 0):.2f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())

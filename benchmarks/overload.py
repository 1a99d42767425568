"""Overload: one arcf-service at three times its capacity, and back.

Spawns a service (one worker per CPU) on loopback, measures its capacity in the same run
(streams of one sequence added one at a time until p99 >= 100 ms or a frame drops), then offers
three times as many streams, then falls back to capacity. Reports per phase: offered and
processed frames/s, the share of frames dropped (oldest first) and counted, the latency of the
processed frames (and its first and second half, to show it does not grow), the service's
memory (anonymous memory of all its processes, trend in MB/min), the time to recover once the
load falls, and the frame ledger (every frame answered or counted as dropped).

    python benchmarks/overload.py                                   # ~4 min per case
    python benchmarks/overload.py --presets arcf-h --fps 10 --sequences wakeboard7 --phase 60

Writes ``overload.json`` and prints a Markdown table (for docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from arcf.client import TrackingClient
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.stress import run_overload
from arcf.loadtools.system import machine


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="arcf-h,arcf-hc")
    ap.add_argument("--fps", default="10,30")
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--sequences", default="wakeboard7")
    ap.add_argument("--factor", type=float, default=3.0)
    ap.add_argument("--phase", type=float, default=60.0, help="seconds per phase")
    ap.add_argument("--step", type=float, default=10.0, help="seconds per capacity step")
    ap.add_argument("--max-streams", type=int, default=16)
    ap.add_argument("--p99-ms", type=float, default=100.0)
    ap.add_argument("--window", type=int, default=40, help="frames replayed forth and back")
    ap.add_argument("--out", default="overload.json")
    args = ap.parse_args()

    from arcf.eval import load_dataset

    wanted = args.sequences.split(",")
    seqs = [s for s in load_dataset(args.dataset) if s.name in wanted]
    out: dict[str, Any] = {"machine": machine(), "runs": []}
    for preset in args.presets.split(","):
        for fps in (float(x) for x in args.fps.split(",")):
            for seq in seqs:
                svc = ServiceProcess(workers=os.cpu_count() or 1)
                t0 = time.monotonic()
                try:
                    with TrackingClient(connect=[svc.endpoint]) as client:
                        r = run_overload(
                            client, [seq], service_pid=svc.pid,
                            metrics_url=svc.metrics_url, preset=preset, fps=fps,
                            factor=args.factor, phase_s=args.phase, step_s=args.step,
                            p99_ms=args.p99_ms, window=args.window,
                            max_streams=args.max_streams,
                            log=lambda m, p=preset, f=fps: print(f"{p} {f:g} fps: {m}",
                                                                 file=sys.stderr))
                except RuntimeError as exc:
                    print(f"# {preset} {fps:g} fps {seq.name}: {exc}", file=sys.stderr)
                    r = {"preset": preset, "fps": fps, "sequences": [seq.name],
                         "skipped": str(exc)}
                finally:
                    code = svc.stop()
                r["service_exit"] = code
                r["minutes"] = (time.monotonic() - t0) / 60
                out["runs"].append(r)
                Path(args.out).write_text(json.dumps(out, indent=1, default=float))
                if "timeline" in r:
                    stem = Path(args.out).with_suffix("")
                    plot(r, Path(f"{stem}-{preset}-{fps:g}fps-{seq.name}.png"))
    print(markdown(out))
    return 0


def plot(r: dict[str, Any], path: Path) -> None:
    """Streams offered, latency of processed frames, share dropped and memory, per second."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tl = r["timeline"]
    t = [row["t"] for row in tl]
    fig, axes = plt.subplots(3, 1, figsize=(7, 6), sharex=True)
    ax = axes[0]
    ax.step(t, [row["streams"] for row in tl], where="post", color="k", label="streams")
    ax.set_ylabel("streams")
    ax2 = ax.twinx()
    dropped = [100 * row["dropped"] / max(row["dropped"] + row["results"], 1) for row in tl]
    ax2.plot(t, dropped, color="tab:red", label="dropped")
    ax2.set_ylabel("dropped (%)", color="tab:red")
    ax2.set_ylim(0, 100)
    ax.set_title(f"{r['preset']}, {r['fps']:g} fps streams of {r['sequences'][0]}: capacity "
                 f"{r['capacity']}, then {r['overload_streams']}, then {r['capacity']}",
                 fontsize=9)
    ax = axes[1]
    ax.plot(t, [row["p50_ms"] for row in tl], label="p50")
    ax.plot(t, [row["p99_ms"] for row in tl], label="p99")
    ax.axhline(r["p99_criterion_ms"], color="grey", ls="--", lw=1, label="capacity criterion")
    ax.set_ylabel("latency (ms)")
    ax.legend(fontsize=8, loc="upper left")
    ax = axes[2]
    ax.plot(t, [row["anon_mb"] for row in tl], color="tab:green")
    ax.set_ylabel("service memory (MB)\nanonymous, all processes", fontsize=8)
    ax.set_xlabel("seconds")
    for a in axes:
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(out: dict[str, Any]) -> str:
    m = out["machine"]
    software = f", {m['software']}" if m.get("software") else ""
    lines = [f"Machine: nproc {m['nproc']}, {m['cpu']}{software}.", "",
             "| preset, fps, sequence | phase | streams | offered / processed (frames/s) | "
             "dropped | latency p50 / p99 / max (ms) | p99 1st / 2nd half (ms) | "
             "memory median / max (MB) | memory trend (MB/min) |",
             "| --- " * 9 + "|"]
    for r in out["runs"]:
        name = f"{r['preset']}, {r['fps']:g}, {r['sequences'][0]}"
        if "skipped" in r:
            lines.append(f"| {name} | skipped: {r['skipped']} |" + " |" * 7)
            continue
        for p in r["phases"]:
            lat, mem = p["latency_ms"], p["memory"]
            lines.append(
                f"| {name} | {p['phase']} | {p['streams']} | {p['offered_fps']:.1f} / "
                f"{p['processed_fps']:.1f} | {100 * p['drop_fraction']:.0f} % | "
                f"{lat['p50']:.0f} / {lat['p99']:.0f} / {lat['max']:.0f} | "
                f"{p['latency_ms_first_half']['p99']:.0f} / "
                f"{p['latency_ms_second_half']['p99']:.0f} | "
                f"{mem['anon_median_mb']:.0f} / {mem['anon_max_mb']:.0f} | "
                f"{mem['anon_trend_mb_per_min']:+.1f} |")
            name = ""
    lines += ["", "| preset, fps, sequence | capacity | overload | recovered after (s) | "
              "ledger: results / dropped / unaccounted / out of order | "
              "arcf_frames_dropped_total | service exit |", "| --- " * 7 + "|"]
    for r in out["runs"]:
        if "skipped" in r:
            continue
        led = r["ledger"]
        lines.append(
            f"| {r['preset']}, {r['fps']:g}, {r['sequences'][0]} | {r['capacity']} | "
            f"{r['overload_streams']} | {r['recovery_s']:.1f} | {led['results']} / "
            f"{led['dropped']} / {led['unaccounted']} / {led['out_of_order']} | "
            f"{r['metrics_delta'].get('arcf_frames_dropped_total', float('nan')):.0f} | "
            f"{r['service_exit']} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())

"""Memory soak: one arcf-service under sustained load, sessions coming and going, for 20 minutes.

Spawns a service (one worker per CPU) on loopback and keeps ``--streams`` streams running, each
for a random 20-60 s (a new one replaces it when it ends; every third with two sessions, every
fifth reusing an old stream id, re-initialised each time its clip starts over), while the
memory of all the service's processes is sampled: anonymous memory (heap and buffers, where a
leak shows), with PSS and RSS beside it. Memory may rise while the service warms up
(allocator pools, OpenCV and FFT buffers, Zenoh's); after ``--warmup`` it must stay flat.

Reported: memory at start, after warm-up and at the end (medians over a window), the linear
trend after warm-up, sessions started and stopped, the frame ledger, and the series itself.

    python benchmarks/soak.py                                # 20 min
    python benchmarks/soak.py --minutes 60 --streams 6 --out soak-60.json

Writes ``soak.json`` (with the memory series) and ``soak.png``, prints a Markdown summary.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

from _common import parser  # beside this script

from arcf.client import TrackingClient
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.stress import run_soak
from arcf.loadtools.system import machine


def main() -> int:
    ap = parser(__doc__, preset="arcf-h", fps=10.0)
    ap.add_argument("--minutes", type=float, default=20.0)
    ap.add_argument("--warmup", type=float, default=120.0, help="seconds")
    ap.add_argument("--streams", type=int, default=3, help="streams at any time")
    ap.add_argument("--lifetime", default="20,60", help="min,max seconds a stream lives")
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--sequences", default="wakeboard7,truck4_1")
    ap.add_argument("--sample", type=float, default=5.0, help="seconds between memory samples")
    ap.add_argument("--out", default="soak.json")
    args = ap.parse_args()

    from arcf.eval import load_dataset

    wanted = args.sequences.split(",")
    seqs = [s for s in load_dataset(args.dataset) if s.name in wanted]
    life = tuple(float(x) for x in args.lifetime.split(","))
    svc = ServiceProcess(workers=os.cpu_count() or 1)
    try:
        with TrackingClient(connect=[svc.endpoint]) as client:
            r = run_soak(client, seqs, service_pid=svc.pid, metrics_url=svc.metrics_url,
                         preset=args.preset, fps=args.fps, streams=args.streams,
                         duration_s=60 * args.minutes, warmup_s=args.warmup,
                         lifetime_s=(life[0], life[1]), sample_s=args.sample,
                         log=lambda m: print(m, file=sys.stderr))
            r["active_sessions_after"] = _gauge(svc, "arcf_active_sessions")
            r["active_streams_after"] = _gauge(svc, "arcf_active_streams")
    finally:
        r_exit = svc.stop()
    r["service_exit"] = r_exit
    r["machine"] = machine()
    out = Path(args.out)
    out.write_text(json.dumps(r, indent=1, default=float))
    plot(r, out.with_suffix(".png"))
    print(markdown(r))
    return 0


def _gauge(svc: ServiceProcess, name: str) -> float:
    return svc.metric(name)


def plot(r: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = r["memory_series"]
    fig, ax = plt.subplots(figsize=(7, 3))
    minutes = [s[0] / 60 for s in series]
    ax.plot(minutes, [s[1] for s in series], label="anonymous")
    ax.plot(minutes, [s[2] for s in series], label="PSS", alpha=0.6)
    ax.plot(minutes, [s[3] for s in series], label="RSS", alpha=0.6)
    ax.axvline(r["warmup_s"] / 60, color="grey", ls="--", lw=1, label="end of warm-up")
    ax.set_xlabel("minutes")
    ax.set_ylabel("MB, all service processes")
    ax.set_title(f"Soak: {r['streams']} streams of {r['preset']} at {r['fps']:g} fps, "
                 f"{r['sessions_started']} sessions started", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(r: dict[str, Any]) -> str:
    m, led, load = r["machine"], r["ledger"], r["load"]
    lat = load["latency_ms"]
    software = f", {m['software']}" if m.get("software") else ""
    return "\n".join([
        f"Machine: nproc {m['nproc']}, {m['cpu']}{software}.", "",
        "| minutes | streams at a time | sessions started / stopped | frames sent | "
        "anonymous memory start / warm / end (MB) | growth after warm-up (MB) | trend (MB/h) | "
        "RSS max (MB) | latency p50 / p99 (ms) | dropped | unaccounted | sessions left |",
        "| --- " * 12 + "|",
        f"| {r['duration_s'] / 60:.0f} | {r['streams']} | {r['sessions_started']} / "
        f"{r['sessions_stopped']} | {r['frames_sent']} | "
        f"{r['memory_start_mb']['anon_median_mb']:.1f} / "
        f"{r['memory_warm_mb']['anon_median_mb']:.1f} / "
        f"{r['memory_end_mb']['anon_median_mb']:.1f} | {r['growth_mb']:+.1f} | "
        f"{60 * r['memory_steady']['anon_trend_mb_per_min']:+.1f} | "
        f"{r['memory_steady']['rss_max_mb']:.0f} | {lat['p50']:.0f} / {lat['p99']:.0f} | "
        f"{100 * load['drop_fraction']:.1f} % | {led['unaccounted']} | "
        f"{r.get('active_sessions_after', float('nan')):.0f} |",
    ]) + "\n"


if __name__ == "__main__":
    sys.exit(main())

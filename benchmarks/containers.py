"""Container figures: image sizes, build time, and failover of the compose stack.

    python benchmarks/containers.py                 # ~4 min with a warm wheelhouse
    python benchmarks/containers.py --cold          # also a build without the layer cache

Builds what an air-gapped site builds (``deploy/offline.py``: Debian base and wheelhouse, then
``compose.yaml`` + ``compose.local.yaml``), brings the stack up on 127.0.0.1 ports with one
worker per instance, and runs the failover trials of ``benchmarks/scaleout.py`` against the
containers: paced streams of a real sequence through the router's published port, then per
trial ``docker kill`` of the instance owning most streams (its streams resume on the other),
``docker-compose start`` of it (it takes its share back), and ``docker pause`` (a frozen
container, found out by the Zenoh lease), then ``docker unpause``. Prints Markdown for
``docs/results-scale.md``, "Containers" and leaves nothing running.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from statistics import median
from typing import Any

from _common import parser  # beside this script

from arcf.client import TrackingClient
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.compose import INSTANCES, ComposeStack, stack_env
from arcf.loadtools.driver import Clip, failover_fleet
from arcf.loadtools.procs import free_port
from arcf.service.cluster import owner

ROOT = Path(__file__).resolve().parent.parent

DEPLOY = ROOT / "deploy"


def trials(args: argparse.Namespace, compose: ComposeStack, router_port: int
           ) -> list[dict[str, Any]]:
    seq = load_dataset("uav123_10fps", sequences=["truck4_1"])[0]
    rows = []
    with TrackingClient(connect=[f"tcp/127.0.0.1:{router_port}"]) as client, \
            failover_fleet(client, Clip.of(seq), [f"cam-{k}" for k in range(args.streams)],
                           preset=args.preset, fps=args.fps,
                           frames=int(args.max_seconds * args.fps)) as fleet:
        streams = [st.name for st in fleet.live]
        time.sleep(4.0)
        for trial in range(args.trials):
            for how in ("kill", "pause"):
                victim = max(INSTANCES, key=lambda i: sum(owner(n, INSTANCES) == i
                                                         for n in streams))
                owned = [n for n in streams if owner(n, INSTANCES) == victim]
                others = [n for n in streams if n not in owned]
                cid = compose.container(victim)
                t0 = time.monotonic()
                subprocess.run(["docker", how, cid], check=True, capture_output=True)
                rows.append({"trial": trial, "event": f"docker {how}",
                             **fleet.ledger.after_move(owned, others, t0, timeout=15,
                                                      gaps_from=t0 - 1.0)})
                print(json.dumps(rows[-1]), file=sys.stderr)
                t0 = time.monotonic()
                if how == "kill":
                    compose("start", victim)
                else:
                    subprocess.run(["docker", "unpause", cid], check=True, capture_output=True)
                rows.append({"trial": trial, "event": "start" if how == "kill" else "unpause",
                             **fleet.ledger.after_move(owned, others, t0, timeout=60)})
                print(json.dumps(rows[-1]), file=sys.stderr)
                compose.wait_healthy(INSTANCES)
    return rows


def image_mb(tag: str) -> float:
    out = subprocess.run(["docker", "image", "inspect", "--format", "{{.Size}}", tag],
                         capture_output=True, text=True, check=True)
    return int(out.stdout.strip()) / 1e6


def main() -> int:
    ap = parser(__doc__, preset="arcf-h", fps=5.0)
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--streams", type=int, default=6)
    ap.add_argument("--max-seconds", type=float, default=300.0)
    ap.add_argument("--cold", action="store_true", help="also time a build without cache")
    args = ap.parse_args()
    t0 = time.monotonic()
    subprocess.run([sys.executable, str(DEPLOY / "offline.py")], check=True)
    prepare_s = time.monotonic() - t0
    router_port, prometheus_port = free_port(), free_port()
    env = stack_env(os.environ, router_port=router_port, prometheus_port=prometheus_port,
                    data=data_root(), version="bench")
    compose = ComposeStack(f"arcfbench{os.getpid()}", env, DEPLOY, prometheus_port)
    builds = {}
    if args.cold:
        t0 = time.monotonic()
        compose("build", "--no-cache", "arcf-1")
        builds["service image, no layer cache, wheelhouse ready"] = time.monotonic() - t0
    (ROOT / "arcf" / ".build-stamp").write_text(str(time.time()))  # a code edit
    try:
        t0 = time.monotonic()
        compose("build", "arcf-1")
        builds["service image after a code edit (wheel layer cached)"] = time.monotonic() - t0
    finally:
        (ROOT / "arcf" / ".build-stamp").unlink()
    t0 = time.monotonic()
    compose("build")
    builds["whole stack, cached"] = time.monotonic() - t0
    try:
        t0 = time.monotonic()
        compose("up", "-d")
        compose.wait_healthy(INSTANCES)
        up_s = time.monotonic() - t0
        rows = trials(args, compose, router_port)
    finally:
        compose.down()
    print(f"machine: {time.strftime('%Y-%m-%d')}, {describe()}; prepare (base + wheelhouse, "
          f"warm): {prepare_s:.0f} s; up to both healthy: {up_s:.0f} s\n")
    print("| image | size (MB) |\n| --- | --- |")
    for tag in ("arcf-base:bookworm", "arcf-build:bookworm", "arcf-service:bench",
                "arcf-prometheus:bench"):
        print(f"| {tag} | {image_mb(tag):.0f} |")
    print("\n| build | seconds |\n| --- | --- |")
    for name, secs in builds.items():
        print(f"| {name} | {secs:.0f} |")
    print("\n| event | trials | streams moved | resumed | event to first resumed result, ms: "
          "median / max | frames lost per moved stream: median / max | gaps on the other "
          "streams |\n| --- | --- | --- | --- | --- | --- | --- |")
    for event in ("docker kill", "start", "docker pause", "unpause"):
        sel = [r for r in rows if r["event"] == event]
        if not sel:
            continue
        ms = [v for r in sel for v in r["failover_ms"]] or [float("nan")]
        lost = [h[0] for r in sel for h in r["handovers"]] or [float("nan")]
        print(f"| {event} | {len(sel)} | {sum(r['streams_moved'] for r in sel)} | "
              f"{sum(r['resumed'] for r in sel)} | {median(ms):.0f} / {max(ms):.0f} | "
              f"{median(lost):.0f} / {max(lost):.0f} | "
              f"{sum(r['other_streams_gaps'] for r in sel)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

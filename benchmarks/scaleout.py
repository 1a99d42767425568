"""Scale-out figures: failover time and frames lost, rebalancing on join, and aggregate
throughput with 1, 2 and 3 instances, all on loopback through one Zenoh router.

    python benchmarks/scaleout.py                       # ~5 min on 2 cores
    python benchmarks/scaleout.py --trials 5 --skip-throughput

Failover: three instances (one worker each) share paced streams of a real sequence. In each
trial the instance owning most streams is killed (SIGKILL), or frozen (SIGSTOP of all its
processes, as ``docker pause`` does: detected only when the Zenoh lease expires). Measured per
stream it owned: kill to the first result from its new owner (status ``resumed``), and the
frames of that stream that got no result. The streams it did not own are checked for gaps in
the same window. A fresh instance then joins, and the same is measured for the streams it takes.

Throughput: closed-loop streams (one frame in flight each) saturate 1 instance with 2 workers,
2 instances with 1 worker each, and 3 instances with 1 worker each (oversubscribed: 3 workers
on 2 cores), and the results per second are compared.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import signal
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent

from arcf.eval import load_dataset  # noqa: E402
from service.client import TrackingClient  # noqa: E402
from service.cluster import owner  # noqa: E402
from service.loadtest import run_load  # noqa: E402
from service.procs import RouterProcess, ServiceProcess  # noqa: E402


def gaps(results: list[tuple[Any, float]], t0: float, t1: float) -> int:
    seqs = sorted({r.frame_seq for r, t in results if t0 <= t <= t1})
    return sum(b - a - 1 for a, b in itertools.pairwise(seqs))


class Fleet:
    """A router, instances joining it, and paced streams with their results."""

    def __init__(self, args: argparse.Namespace, seq: Any) -> None:
        self.args = args
        self.seq = seq
        self.frames = [p.read_bytes() for p in seq.frames]
        self.router = RouterProcess()
        self.instances: dict[str, ServiceProcess] = {}
        self.counter = 0
        self.results: dict[str, list[tuple[Any, float]]] = defaultdict(list)
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.client: TrackingClient | None = None

    def add(self, n: int = 1) -> list[str]:
        names = [f"inst-{self.counter + k}" for k in range(n)]
        self.counter += n

        def start(name: str) -> tuple[str, ServiceProcess]:
            return name, ServiceProcess("--instance-id", name, "--lease-ms",
                                        str(self.args.lease_ms), connect=self.router.endpoint,
                                        workers=1, quiet=False)

        threads = []
        out: list[tuple[str, ServiceProcess]] = []
        for name in names:
            t = threading.Thread(target=lambda n=name: out.append(start(n)))
            t.start()
            threads.append(t)
        for t in threads:
            t.join()
        self.instances.update(out)
        return names

    def live(self) -> list[str]:
        return [n for n, s in self.instances.items() if s.proc.poll() is None]

    def start_streams(self) -> list[str]:
        self.client = TrackingClient(connect=[self.router.endpoint])
        self.streams = [f"cam-{k}" for k in range(self.args.streams)]
        for name in self.streams:
            def on_result(r: Any, name: str = name) -> None:
                with self.lock:
                    self.results[name].append((r, time.monotonic()))
            self.client.results(name, callback=on_result)
            self.client.start(name, self.seq.init_box, preset=self.args.preset,
                              session_id=f"s-{name}", frame_seq=0)
        threading.Thread(target=self._publish, daemon=True).start()
        return self.streams

    def _publish(self) -> None:
        assert self.client is not None
        t0, i = time.monotonic(), 0
        limit = int(self.args.max_seconds * self.args.fps)
        while not self.stop.is_set() and i < limit:
            for name in self.streams:
                self.client.publish_frame(name, data=self.frames[i % len(self.frames)], seq=i)
            i += 1
            time.sleep(max(0.0, t0 + i / self.args.fps - time.monotonic()))

    def resumed_after(self, streams: list[str], t0: float, timeout: float) -> dict[str, float]:
        deadline = time.monotonic() + timeout
        found: dict[str, float] = {}
        while time.monotonic() < deadline and len(found) < len(streams):
            with self.lock:
                for n in streams:
                    hit = [t for r, t in self.results[n] if r.status.value == "resumed" and t > t0]
                    if hit:
                        found[n] = min(hit)
            time.sleep(0.01)
        return found

    def handover(self, name: str, t_resumed: float) -> tuple[int, float]:
        """(frames with no result, ms without a result) of a stream at a handover: between
        the result before its first ``resumed`` one and that one."""
        with self.lock:
            first, t_first = min((r.frame_seq, t) for r, t in self.results[name]
                                 if r.status.value == "resumed" and t >= t_resumed)
            before = [(r.frame_seq, t) for r, t in self.results[name] if r.frame_seq < first]
        last, t_last = max(before) if before else (-1, t_first)
        return first - last - 1, 1e3 * (t_first - t_last)

    def close(self) -> None:
        self.stop.set()
        if self.client is not None:
            self.client.close()
        for s in self.instances.values():
            if s.proc.poll() is None:
                s.stop()
        self.router.stop()


def pids_of(svc: ServiceProcess) -> list[int]:
    from service.loadtest import _process_tree

    return sorted(_process_tree(svc.proc.pid))


def failover(args: argparse.Namespace, seq: Any) -> list[dict[str, Any]]:
    fleet = Fleet(args, seq)
    rows = []
    try:
        fleet.add(3)
        streams = fleet.start_streams()
        time.sleep(3.0)
        for trial in range(args.trials):
            for how in ("SIGKILL", "SIGSTOP"):
                live = fleet.live()
                victim = max(live, key=lambda i: sum(owner(n, live) == i for n in streams))
                owned = [n for n in streams if owner(n, live) == victim]
                others = [n for n in streams if n not in owned]
                svc = fleet.instances[victim]
                t_kill = time.monotonic()
                if how == "SIGKILL":
                    svc.proc.send_signal(signal.SIGKILL)
                else:  # the whole instance frozen, as docker pause does
                    for pid in pids_of(svc):
                        os.kill(pid, signal.SIGSTOP)
                found = fleet.resumed_after(owned, t_kill, timeout=args.lease_ms / 1e3 + 10)
                time.sleep(1.5)
                t_end = time.monotonic()
                row = {"trial": trial, "event": how, "instances_before": len(live),
                       "streams_moved": len(owned),
                       "resumed": len(found),
                       "failover_ms": [1e3 * (found[n] - t_kill) for n in owned if n in found],
                       "handovers": [fleet.handover(n, found[n]) for n in owned if n in found],
                       "other_streams_gaps": sum(gaps(fleet.results[n], t_kill - 1.0, t_end)
                                                 for n in others)}
                rows.append(row)
                print(json.dumps(row), file=sys.stderr)
                if how == "SIGSTOP":
                    for pid in pids_of(svc):
                        os.kill(pid, signal.SIGKILL)
                    for pid in pids_of(svc):
                        os.kill(pid, signal.SIGCONT)
                svc.proc.wait(timeout=10)
                # a fresh instance joins and takes its share
                live = fleet.live()
                t_join = time.monotonic()
                (new,) = fleet.add(1)
                joined = [*live, new]
                moving = [n for n in streams if owner(n, joined) == new]
                staying = [n for n in streams if n not in moving]
                found = fleet.resumed_after(moving, t_join, timeout=15)
                time.sleep(1.5)
                row = {"trial": trial, "event": "join", "instances_before": len(live),
                       "streams_moved": len(moving), "resumed": len(found),
                       # from the instance's start: it needs ~2-4 s to spawn and warm its worker
                       "failover_ms": [1e3 * (found[n] - t_join) for n in moving if n in found],
                       "handovers": [fleet.handover(n, found[n]) for n in moving if n in found],
                       "other_streams_gaps": sum(gaps(fleet.results[n], t_join,
                                                      time.monotonic()) for n in staying)}
                rows.append(row)
                print(json.dumps(row), file=sys.stderr)
    finally:
        fleet.close()
    return rows


def throughput(args: argparse.Namespace, seq: Any) -> list[dict[str, Any]]:
    rows = []
    for n_instances, workers in ((1, 2), (2, 1), (3, 1)):
        router = RouterProcess()
        instances = []
        try:
            for k in range(n_instances):
                instances.append(ServiceProcess("--instance-id", f"tp-{k}", connect=router.endpoint,
                                                workers=workers, quiet=False))
            r = run_load([router.endpoint], [seq], streams=args.streams, preset=args.preset,
                         fps=0, in_flight=1, loop=True, duration=args.throughput_seconds,
                         offline=False, reference_seconds=0, progress=False)
            row = {"instances": n_instances, "workers_per_instance": workers,
                   "results_per_s": r["processed_fps"], "p50_ms": r["latency_ms"]["p50"],
                   "p99_ms": r["latency_ms"]["p99"], "missing": r["missing"],
                   "dropped": r["dropped_by_service"]}
            rows.append(row)
            print(json.dumps(row), file=sys.stderr)
        finally:
            for s in instances:
                s.stop()
            router.stop()
    return rows


def markdown(out: dict[str, Any]) -> str:
    import numpy as np

    lines = []
    if out.get("failover"):
        lines += ["| event | trials | streams moved | resumed | event to first resumed result, "
                  "ms: median / max | moved stream without results, ms: median / max | frames "
                  "lost per moved stream: median / max | gaps on the other streams |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for event in ("SIGKILL", "SIGSTOP", "join"):
            rows = [r for r in out["failover"] if r["event"] == event]
            if not rows:
                continue
            ms = [x for r in rows for x in r["failover_ms"]]
            lost = [h[0] for r in rows for h in r["handovers"]]
            gap = [h[1] for r in rows for h in r["handovers"]]
            lines.append(
                f"| {event} | {len(rows)} | {sum(r['streams_moved'] for r in rows)} | "
                f"{sum(r['resumed'] for r in rows)} | {np.median(ms):.0f} / {max(ms):.0f} | "
                f"{np.median(gap):.0f} / {max(gap):.0f} | {np.median(lost):.0f} / {max(lost)} | "
                f"{sum(r['other_streams_gaps'] for r in rows)} |")
    if out.get("throughput"):
        lines += ["", "| instances | workers each | results/s | p50 / p99 latency (ms) | "
                  "dropped | missing |", "| --- | --- | --- | --- | --- | --- |"]
        for r in out["throughput"]:
            lines.append(f"| {r['instances']} | {r['workers_per_instance']} | "
                         f"{r['results_per_s']:.1f} | {r['p50_ms']:.0f} / {r['p99_ms']:.0f} | "
                         f"{r['dropped']} | {r['missing']} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default="truck4_1")
    ap.add_argument("--dataset", default="uav123_10fps")
    ap.add_argument("--preset", default="arcf-h")
    ap.add_argument("--streams", type=int, default=6)
    ap.add_argument("--fps", type=float, default=5.0, help="per stream, failover part")
    ap.add_argument("--lease-ms", type=int, default=3000)
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--max-seconds", type=float, default=600.0, help="bound on publishing")
    ap.add_argument("--throughput-seconds", type=float, default=20.0)
    ap.add_argument("--skip-failover", action="store_true")
    ap.add_argument("--skip-throughput", action="store_true")
    ap.add_argument("--out", default="scaleout.json")
    args = ap.parse_args()
    seq = load_dataset(args.dataset, sequences=[args.sequence])[0]
    out: dict[str, Any] = {"args": vars(args), "nproc": os.cpu_count()}
    if not args.skip_failover:
        out["failover"] = failover(args, seq)
    if not args.skip_throughput:
        out["throughput"] = throughput(args, seq)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(markdown(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

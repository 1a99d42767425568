"""What a hostile station costs the others: a victim's latency and frames with and without
each attack, against one arcf-service on loopback.

    python benchmarks/hostile.py                 # ~5 min on 2 cores
    python benchmarks/hostile.py --phase-s 20 --workers 2

Two victim streams (ARCF-H, 10 fps, real UAV123 frames) run throughout, by default on the
service's one worker (``--workers 1``): whatever the attacker's stream costs, it costs on
the victims' worker. Each phase runs one attack next to them for ``--phase-s`` seconds, with
a quiet phase first for reference; the worker's peak resident memory is sampled every 0.5 s:

- wildcard: frames numbered 10^12 and garbage put on ``streams/*/frames`` and ``**`` (20/s);
- rogue-seq: frames numbered 10^12 + k put on the first victim's own key (10/s);
- flood: a station floods its own stream at ~500 frames/s (limit 60/s);
- overrides: start requests with out-of-range overrides (20/s), all refused;
- oversized: 12 MiB frames on the attacker's stream (4/s), refused;
- vanishing: a station starts 30 sessions and is SIGKILLed (freed after the grace);
- heavy-neighbour: not an attack: an ARCF-HC session added on the first victim's stream
  (all sessions of a stream share its worker, so the frame is decoded once);
- big-h264: an H.264 stream whose parameter set declares 6000 x 6000 (36 MP), skip units at
  30/s and a keyframe every 30, with a session (refused at the parameter set: max_pixels);
- big-cdr: the same as foxglove.CompressedVideo on ``video/<stream>/stream``;
- 4k-h264: the same at 3840 x 2160, within max_pixels: decoded, converted only when tracked;
- dense-starts: 2 MiB units of bare IDR start codes (``00 00 01 65``), 10/s;
- delimiters: 8 MiB H.265 units of access-unit delimiters (``00 00 01 46 01``), 5/s;
- heavy-sessions: twelve ARCF-HC sessions on one attacker stream at 10 fps, more than the
  worker has: the costliest are shed (worker_budget).

Prints a Markdown table (for docs/benchmarks.md) and writes hostile.json.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from arcf.client import ServiceError, TrackingClient
from arcf.client.foxglove import compressed_video
from arcf.eval import load_dataset
from arcf.loadtools.driver import Clip, Fleet, Pacing
from arcf.loadtools.procs import ServiceProcess
from arcf.loadtools.system import machine
from arcf.loadtools.video import encode_video
from arcf.schemas import Frame, KeySpace, encode
from arcf.service.scrape import by_label, delta, fetch, scrape, series

KEYS = KeySpace()


def errors_by_kind(url: str) -> dict[str, float]:
    return by_label(fetch(url), "arcf_errors_total", "kind")


def worker_rss_mb(url: str) -> float:
    """The largest resident set among the service's worker processes, MB."""
    rows = series(fetch(url)).get("arcf_process_resident_bytes", [])
    return max((v for labels, v in rows if labels.get("process", "").startswith("worker")),
               default=0.0) / 2**20


def skip_stream(width: int, height: int) -> list[bytes]:
    """A keyframe then 29 skip units of a black picture: what a camera sends of a still
    scene, a few KB a second on the wire whatever the picture's size."""
    units = encode_video([np.zeros((height, width, 3), np.uint8)] * 3, "h264", fps=30,
                         gop=1000)
    return [units[0]] + [units[2]] * 29


def repeat(every_s: float, action: Callable[[int], None], stop: threading.Event) -> None:
    k = 0
    while not stop.wait(every_s):
        action(k)
        k += 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--phase-s", type=float, default=15.0)
    ap.add_argument("--out", default="hostile.json")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    clip = Clip.of(seq, limit=60, palindrome=True)
    frame0 = clip.frames[0]
    rows: list[dict[str, Any]] = []
    big, four_k = skip_stream(6000, 6000), skip_stream(3840, 2160)
    with ServiceProcess(workers=args.workers, quiet=True) as svc, \
            TrackingClient(connect=[svc.endpoint]) as client, \
            TrackingClient(connect=[svc.endpoint]) as attacker:
        assert svc.metrics_url is not None
        fleet = Fleet(client, [clip], preset="arcf-h", pacing=Pacing.fixed_rate(10.0),
                      prefix="victim")
        victims = fleet.add(2)
        time.sleep(3.0)

        def wildcard(k: int) -> None:
            rogue = encode(Frame(stream_id=victims[0].name, seq=10**12 + k, capture_ts_ns=1,
                                 encoding="jpeg", payload=frame0))
            attacker.session.put(KEYS.all_frames(), rogue if k % 2 else b"\x00garbage")
            attacker.session.put(f"{KEYS.prefix}/**", rogue)

        def rogue_seq(k: int) -> None:
            attacker.session.put(KEYS.frames(victims[0].name), encode(Frame(
                stream_id=victims[0].name, seq=10**12 + 2 * k, capture_ts_ns=1,
                encoding="jpeg", payload=frame0)))

        flood_ack: list[Any] = []

        def flood(k: int) -> None:
            if not flood_ack:
                flood_ack.append(attacker.start("flooder", clip.box, preset="bacf"))
            attacker.publish_frame("flooder", data=clip.frames[k % len(clip)], seq=k)

        def overrides(k: int) -> None:
            with contextlib.suppress(ServiceError):  # refused: that is the point
                attacker.start(f"over-{k}", clip.box, preset="arcf-hc",
                               overrides={"admm_iterations": 4000})

        junk = os.urandom(12 << 20)

        def oversized(k: int) -> None:
            if not flood_ack:
                flood_ack.append(attacker.start("big", clip.box, preset="bacf"))
            attacker.session.put(KEYS.frames("big"), encode(Frame(
                stream_id="big", seq=k, capture_ts_ns=1, encoding="jpeg", payload=junk)))

        def video(units: list[bytes], encoding: str = "h264", cdr: bool = False
                  ) -> Callable[[int], None]:
            def send(k: int) -> None:
                if not flood_ack:
                    flood_ack.append(attacker.start("vid", [100, 100, 60, 60], preset="bacf"))
                unit = units[k % len(units)]
                if cdr:
                    attacker.session.put("video/vid/stream", compressed_video(
                        unit, encoding, time.time_ns()))
                else:
                    attacker.publish_frame("vid", data=unit, seq=k, encoding=encoding)
            return send

        heavy_sessions: list[Any] = []

        def heavy_neighbours(k: int) -> None:
            if not heavy_sessions:
                heavy_sessions.extend(attacker.start("heavy", clip.box, preset="arcf-hc")
                                      for _ in range(12))
            attacker.publish_frame("heavy", data=clip.frames[k % len(clip)], seq=k)

        def vanishing(k: int) -> None:
            if k:
                return
            script = ("import time\nfrom arcf.client import TrackingClient\n"
                      f"c = TrackingClient(connect=[{svc.endpoint!r}])\n"
                      f"[c.start(f'gone-{{j}}', {list(clip.box)!r}, preset='bacf') "
                      "for j in range(30)]\nprint('started', flush=True)\ntime.sleep(60)\n")
            station = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                                       text=True)
            assert station.stdout is not None
            started = station.stdout.readline()
            if started != "started\n":
                raise RuntimeError(f"the vanishing station did not start: {started!r}")
            station.kill()
            station.wait()

        heavy: list[Any] = []

        def heavy_neighbour(k: int) -> None:
            if not heavy:
                heavy.append(client.start(victims[0].name, clip.box, preset="arcf-hc"))

        phases: list[tuple[str, float, Callable[[int], None] | None]] = [
            ("quiet", 1.0, None), ("wildcard", 0.1, wildcard), ("rogue-seq", 0.1, rogue_seq),
            ("flood", 0.002, flood), ("overrides", 0.05, overrides),
            ("oversized", 0.25, oversized), ("vanishing", 1.0, vanishing),
            ("heavy-neighbour", 1.0, heavy_neighbour),
            ("big-h264", 1 / 30, video(big)), ("big-cdr", 1 / 30, video(big, cdr=True)),
            ("4k-h264", 1 / 30, video(four_k)),
            ("dense-starts", 0.1, video([b"\x00\x00\x01\x65" * (1 << 19)])),
            ("delimiters", 0.2, video([b"\x00\x00\x01\x46\x01" * ((8 << 20) // 5 - 64)],
                                      "h265")),
            ("heavy-sessions", 0.1, heavy_neighbours)]
        for name, every_s, action in phases:
            flood_ack.clear()
            before, errors0 = scrape(svc.metrics_url), errors_by_kind(svc.metrics_url)
            stop = threading.Event()
            thread = None
            if action is not None:
                thread = threading.Thread(target=repeat, args=(every_s, action, stop),
                                          daemon=True)
                thread.start()
            t0 = time.monotonic()
            peak = worker_rss_mb(svc.metrics_url)
            while time.monotonic() < t0 + args.phase_s:
                time.sleep(0.5)
                peak = max(peak, worker_rss_mb(svc.metrics_url))
            t1 = time.monotonic()
            stop.set()
            if thread is not None:
                thread.join(timeout=30)
            for ack in [*flood_ack, *heavy_sessions]:
                with contextlib.suppress(ServiceError, TimeoutError):  # shed already
                    attacker.stop(ack.session_id)
            heavy_sessions.clear()
            for ack in heavy:
                client.stop(ack.session_id)
            heavy.clear()
            window = fleet.window(t0 + 1.0, t1, victims)
            first = fleet.window(t0 + 1.0, t1, victims[:1])
            errors1 = errors_by_kind(svc.metrics_url)
            refused = {k: int(v - errors0.get(k, 0)) for k, v in errors1.items()
                       if v - errors0.get(k, 0) > 0}
            moved = delta(before, scrape(svc.metrics_url))
            row = {"phase": name, "victim_offered_fps": window["offered_fps"],
                   "victim_processed_fps": window["processed_fps"],
                   "victim_dropped": window["dropped"], "victim_errors": window["errors"],
                   "p50_ms": window["latency_ms"]["p50"], "p99_ms": window["latency_ms"]["p99"],
                   "first_victim_p99_ms": first["latency_ms"]["p99"],
                   "refused": refused, "worker_peak_rss_mb": peak,
                   "resyncs": {k: int(v) for k, v in by_label(
                       fetch(svc.metrics_url), "arcf_video_resyncs_total", "cause").items()},
                   "shed": int(moved.get("arcf_sessions_shed_total", 0.0)),
                   "frames_dropped_total": moved.get("arcf_frames_dropped_total", 0.0)}
            rows.append(row)
            print(json.dumps(row), file=sys.stderr)
            time.sleep(2.0)
        fleet.close()
        accounting = fleet.ledger.accounting()
    out = {"machine": machine(), "phase_s": args.phase_s, "rows": rows,
           "victim_accounting": accounting}
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    m = out["machine"]
    print(f"`python benchmarks/hostile.py --phase-s {args.phase_s:g} --workers {args.workers}`"
          f", {time.strftime('%Y-%m-%d')}. Machine: nproc {m['nproc']}, {m['cpu']}, "
          f"{m['software']}; two "
          f"victim ARCF-H streams at 10 fps on the attacker's worker ({args.workers} worker(s)); "
          f"{args.phase_s:g} s per phase (victim figures from its second second on).\n")
    print("| phase | victim frames/s offered / processed | victim dropped | victim p50 / p99 "
          "(ms) | worker peak RSS (MB) | refused (arcf_errors_total by kind) | sessions shed |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        refused_text = ", ".join(f"{k} {v}" for k, v in sorted(r["refused"].items())) or "none"
        print(f"| {r['phase']} | {r['victim_offered_fps']:.1f} / {r['victim_processed_fps']:.1f}"
              f" | {r['victim_dropped']} | {r['p50_ms']:.0f} / {r['p99_ms']:.0f} | "
              f"{r['worker_peak_rss_mb']:.0f} | {refused_text} | {r['shed']} |")
    print(f"\nVictim accounting over the whole run: {accounting}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

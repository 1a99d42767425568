"""What a hostile client costs the adapters: ``arcf-mavlink`` and ``arcf-view`` as their own
processes in front of one arcf-service on loopback, a well-behaved client measured before
and during each attack, the adapter's peak resident memory and CPU.

    python benchmarks/hostile_adapters.py        # ~2 min on 2 cores

A victim stream (``cam1``: UAV123@10fps wakeboard7 JPEG frames at 10 fps) runs throughout.

``arcf-mavlink`` (udpin on loopback, cameras ``cam1`` and ``bomb``), the victim a ground
station asking ``cam1`` for ``CAMERA_INFORMATION`` 5 times a second (its acknowledgement's
round trip):

- quiet;
- refused-commands: 20,000 distinct track rectangles that are denied (corners swapped);
- spoofed-ports: heartbeats of a ground station forged from 3,000 source ports;
- png-bomb: the ``bomb`` stream's frames are 12000 x 12000 RGBA-16 PNGs, and the station
  asks that camera to track.

``arcf-view``, the victim a viewer on another loopback address (127.0.0.2) watching ``cam1``
as the page does: the stream list (checked), then the next picture after the last one it
got (timed: at ``--max-fps`` 5, one every 200 ms when all is well):

- quiet;
- lazy-viewers: 16 results connections from 127.0.0.1 that never read;
- half-sent: 500 connections that send half a request line;
- png-bomb: ``cam1`` watched while bomb frames arrive;
- long-query: ``?after=`` with 5,000 digits;
- and at the end SIGTERM: its exit code.

Prints Markdown tables (docs/results-robustness.md, "Hostile clients of the adapters") and writes
hostile_adapters.json.
"""

from __future__ import annotations

import argparse
import contextlib
import http.client
import json
import os
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib
from collections.abc import Callable
from typing import Any

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from arcf.client import TrackingClient
from arcf.eval import load_dataset
from arcf.loadtools.groundstation import GroundStation
from arcf.loadtools.procs import ServiceProcess, free_port, terminate
from arcf.loadtools.system import machine

mav = mavutil.mavlink


def png_bomb(width: int, height: int) -> bytes:
    """A real PNG of ``width`` x ``height`` RGBA-16 zeros: about 1 MB on the wire for
    12000 x 12000, 1.1 GB decoded."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))

    comp = zlib.compressobj(9)
    row = b"\x00" * (8 * width + 1)
    idat = b"".join(comp.compress(row) for _ in range(height)) + comp.flush()
    ihdr = struct.pack(">IIBBBBB", width, height, 16, 6, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat)
            + chunk(b"IEND", b""))


class Adapter:
    """An adapter's process (``python -m <module> ...``), its memory and CPU from /proc."""

    def __init__(self, module: str, args: list[str]) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", module, *args],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def rss_mb(self) -> float:
        with open(f"/proc/{self.proc.pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
        return 0.0

    def threads(self) -> int:
        with open(f"/proc/{self.proc.pid}/status") as f:
            for line in f:
                if line.startswith("Threads:"):
                    return int(line.split()[1])
        return 0

    def cpu_s(self) -> float:
        with open(f"/proc/{self.proc.pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> int:
        return terminate(self.proc, timeout=20)


def percentiles(values: list[float]) -> tuple[float, float]:
    if not values:
        return float("nan"), float("nan")
    return float(np.percentile(values, 50)), float(np.percentile(values, 99))


def phase(name: str, adapter: Adapter, seconds: float, probe: Callable[[], float | None],
          attack: Callable[[threading.Event], None] | None) -> dict[str, Any]:
    """``probe`` (the victim's one request: its seconds, None when it failed) 5 times a
    second for ``seconds`` while ``attack`` runs in a thread; the adapter sampled."""
    stop = threading.Event()
    thread = threading.Thread(target=attack, args=(stop,), daemon=True) if attack else None
    cpu0, t0 = adapter.cpu_s(), time.monotonic()
    if thread is not None:
        thread.start()
    times: list[float] = []
    failed, peak, threads = 0, adapter.rss_mb(), adapter.threads()
    while time.monotonic() - t0 < seconds:
        took = probe()
        if took is None:
            failed += 1
        else:
            times.append(1e3 * took)
        peak, threads = max(peak, adapter.rss_mb()), max(threads, adapter.threads())
        time.sleep(0.2)
    stop.set()
    if thread is not None:
        thread.join(timeout=60)
    wall = time.monotonic() - t0
    p50, p99 = percentiles(times)
    row = {"phase": name, "answered": len(times), "failed": failed, "p50_ms": p50,
           "p99_ms": p99, "peak_rss_mb": peak, "threads": threads,
           "cpu_share": (adapter.cpu_s() - cpu0) / wall, "after_rss_mb": adapter.rss_mb()}
    print(json.dumps(row), file=sys.stderr)
    return row


def mavlink_rows(svc: ServiceProcess, bomb: bytes, seconds: float) -> list[dict[str, Any]]:
    port = free_port()
    adapter = Adapter("arcf.adapters.mavlink", ["--camera", "cam1", "--camera", "bomb=101",
                                           "--mavlink", f"udpin:127.0.0.1:{port}",
                                           "-e", svc.endpoint, "--preset", "bacf"])
    station = GroundStation(port, 100)
    deadline = time.monotonic() + 60
    while not station.since(0, "HEARTBEAT") and time.monotonic() < deadline:
        time.sleep(0.1)

    def probe() -> float | None:
        t0 = time.monotonic()
        station.conn.mav.command_long_send(1, 100, mav.MAV_CMD_REQUEST_MESSAGE, 0,
                                           mav.MAVLINK_MSG_ID_CAMERA_INFORMATION, 0, 0, 0, 0,
                                           0, 0)
        while time.monotonic() - t0 < 2.0:
            with station._lock:
                acks = [t for t, m in station.received if t >= t0
                        and m.get_type() == "COMMAND_ACK"
                        and m.command == mav.MAV_CMD_REQUEST_MESSAGE]
            if acks:
                return acks[0] - t0  # when it arrived, not when this loop looked
            time.sleep(0.002)
        return None

    def refused(stop: threading.Event) -> None:
        attacker = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=254)
        for k in range(20_000):
            if stop.is_set():
                break
            x = 0.5 + 0.4 * k / 20_000
            attacker.mav.command_long_send(1, 100, mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0,
                                           x, 0.5, x - 0.1, 0.6, 0, 0, 0)  # swapped: denied
            if k % 200 == 199:
                time.sleep(0.01)
        attacker.close()

    def spoofed(stop: threading.Event) -> None:
        beat = mav.MAVLink(None, srcSystem=250, srcComponent=190)
        packet = beat.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                       mav.MAV_STATE_ACTIVE).pack(beat)
        socks = []
        try:
            for _ in range(3000):
                if stop.is_set():
                    break
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.sendto(packet, ("127.0.0.1", port))
                socks.append(s)
            while not stop.wait(1.0):  # every port keeps beating
                for s in socks:
                    s.sendto(packet, ("127.0.0.1", port))
        finally:
            for s in socks:
                s.close()

    bomb_ack: list[Any] = []

    def bombed(stop: threading.Event) -> None:
        with TrackingClient(connect=[svc.endpoint]) as c:
            k = 0
            while not stop.wait(0.5):
                c.publish_frame("bomb", data=bomb, encoding="png", seq=k)
                k += 1
                if k == 3:
                    t0 = time.monotonic()
                    with contextlib.suppress(AssertionError):
                        bomb_ack.append((station.command(
                            mav.MAV_CMD_CAMERA_TRACK_RECTANGLE, 0.4, 0.4, 0.5, 0.5,
                            component=101, timeout=20), time.monotonic() - t0))

    rows = []
    for name, attack in (("quiet", None), ("refused-commands", refused),
                         ("spoofed-ports", spoofed), ("png-bomb", bombed)):
        rows.append({"adapter": "arcf-mavlink", **phase(name, adapter, seconds, probe, attack)})
    if bomb_ack:
        (result, texts), took = bomb_ack[0]
        rows[-1]["note"] = (f"track command on the bomb: MAV_RESULT {result} in "
                            f"{1e3 * took:.0f} ms (with the station's 50 ms wait for its "
                            f"STATUSTEXT), {' '.join(texts)[:90]!r}")
    station.close()
    rows[-1]["exit_code"] = adapter.stop()
    return rows


def view_rows(svc: ServiceProcess, bomb: bytes, seconds: float) -> list[dict[str, Any]]:
    port = free_port()
    adapter = Adapter("arcf.adapters.liveview", ["--port", str(port), "-e", svc.endpoint])
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 1):
            break
        time.sleep(0.2)

    seen = [0]
    # as the page does: the stream's results followed (read) all along, which keeps the
    # stream watched; the pictures fetched one after another
    page = socket.create_connection(("127.0.0.1", port), 5, source_address=("127.0.0.2", 0))
    page.sendall(b"GET /api/streams/cam1/results HTTP/1.1\r\nHost: v\r\n\r\n")
    reading = threading.Event()
    reading.set()

    def follow() -> None:
        page.settimeout(1.0)
        while reading.is_set():
            with contextlib.suppress(TimeoutError, OSError):
                if not page.recv(65536):
                    return

    threading.Thread(target=follow, daemon=True).start()

    def request(path: str, timeout: float = 12.0) -> int:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout,
                                          source_address=("127.0.0.2", 0))
        try:
            conn.request("GET", path)
            response = conn.getresponse()
            response.read()
            if response.status == 200 and response.getheader("X-Rendered"):
                seen[0] = int(response.getheader("X-Rendered") or 0)
            return response.status
        finally:
            conn.close()

    def probe() -> float | None:
        try:
            if request("/api/streams") != 200:
                return None
            t0 = time.monotonic()
            ok = request(f"/api/streams/cam1/frame.jpg?after={seen[0]}") == 200
        except OSError:
            return None
        return time.monotonic() - t0 if ok else None

    def holding(count: int, request: bytes, *, skip_refused: bool = False
                ) -> Callable[[threading.Event], None]:
        """An attack of ``count`` connections that each send ``request`` and then hold still
        until the phase ends. ``skip_refused``: a connection the view refuses or resets is
        left out (hundreds of them may meet a full backlog); otherwise it ends the attack."""
        def attack(stop: threading.Event) -> None:
            socks = []
            for _ in range(count):
                with contextlib.suppress(OSError) if skip_refused else contextlib.nullcontext():
                    s = socket.create_connection(("127.0.0.1", port), 5)
                    s.sendall(request)
                    socks.append(s)
            stop.wait()
            for s in socks:
                s.close()
        return attack

    lazy = holding(16, b"GET /api/streams/cam1/results HTTP/1.1\r\nHost: v\r\n\r\n")
    half_sent = holding(500, b"GET /api/str", skip_refused=True)

    def bombed(stop: threading.Event) -> None:
        watcher = socket.create_connection(("127.0.0.1", port), 5)
        watcher.sendall(b"GET /api/streams/cam1/frame.jpg?after=0 HTTP/1.1\r\nHost: v\r\n\r\n")
        with TrackingClient(connect=[svc.endpoint]) as c:
            k = 0
            while not stop.wait(0.5):
                c.publish_frame("cam1", data=bomb, encoding="png", seq=10**6 + k)
                k += 1
        watcher.close()

    long_query: list[int] = []

    def digits(stop: threading.Event) -> None:
        with contextlib.suppress(OSError):
            long_query.append(request("/api/streams/cam1/frame.jpg?after=" + "9" * 5000))

    rows = []
    for name, attack in (("quiet", None), ("lazy-viewers", lazy), ("half-sent", half_sent),
                         ("png-bomb", bombed), ("long-query", digits)):
        rows.append({"adapter": "arcf-view", **phase(name, adapter, seconds, probe, attack)})
    reading.clear()
    page.close()
    rows[-1]["note"] = f"the 5,000-digit query answered {long_query or 'never'}"
    rows[-1]["exit_code"] = adapter.stop()
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--phase-s", type=float, default=10.0)
    ap.add_argument("--out", default="hostile_adapters.json")
    args = ap.parse_args()
    (seq,) = load_dataset("uav123_10fps", sequences=["wakeboard7"])
    frames = [p.read_bytes() for p in seq.frames]
    bomb = png_bomb(12000, 12000)
    stop = threading.Event()
    with ServiceProcess(workers=1) as svc, \
            TrackingClient(connect=[svc.endpoint]) as client:
        def victim() -> None:  # cam1 at 10 fps, bounded: ten minutes
            for k in range(6000):
                if stop.wait(0.1):
                    return
                client.publish_frame("cam1", data=frames[k % len(frames)], seq=k)

        sender = threading.Thread(target=victim, daemon=True)
        sender.start()
        client.start("cam1", seq.init_box, preset="bacf")
        try:
            rows = mavlink_rows(svc, bomb, args.phase_s) + view_rows(svc, bomb, args.phase_s)
        finally:
            stop.set()
            sender.join(timeout=5)
    out = {"machine": machine(), "phase_s": args.phase_s, "rows": rows}
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    m = out["machine"]
    print(f"`python benchmarks/hostile_adapters.py --phase-s {args.phase_s:g}`, "
          f"{time.strftime('%Y-%m-%d')}. Machine: nproc {m['nproc']}, {m['cpu']}, "
          f"{m['software']}.\n")
    print("| adapter | phase | victim answered / failed | victim p50 / p99 (ms) | adapter peak "
          "RSS (MB) | adapter threads (peak) | adapter CPU (share of a core) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['adapter']} | {r['phase']} | {r['answered']} / {r['failed']} | "
              f"{r['p50_ms']:.1f} / {r['p99_ms']:.1f} | {r['peak_rss_mb']:.0f} | "
              f"{r['threads']} | {r['cpu_share']:.2f} |")
    for r in rows:
        for key in ("note", "exit_code"):
            if key in r:
                print(f"\n- {r['adapter']} {r['phase']}: {key.replace('_', ' ')} {r[key]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

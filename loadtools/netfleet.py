"""A fleet over real links: three hosts, each a network namespace with its Zenoh router and
one service instance, stations in a fourth, and one host's link put through faults by phase.
The scenario of ``tests/service/test_netns.py`` and ``benchmarks/netns_fleet.py``.

Layout (:class:`~arcf.loadtools.netlab.NetLab`): each host's router listens on the host's
loopback, and a relay (:mod:`arcf.loadtools.relay`) carries the host's address, port 7447,
to it, so that every connection reaching host 1 from elsewhere crosses host 1's relay (the
routers join as a mesh, each connecting to the hosts before it). Each instance connects to
its own router first, the others' addresses after. The station lists every host, host 1
first: it is linked to host 1's router, and so is everything it sends.

Phases, each ``phase_s`` long, on host 1's link:

1. ``clean``: as built;
2. ``slow``: ``delay_ms`` each way (the relay) and ``loss`` of the packets dropped at random
   each way (the kernel, iptables);
3. ``cut``: host 1's port on the switch is down, a partition: host 1's router and instance
   are alone, the station relinks to host 2 once the Zenoh lease gives host 1 up, and the
   instances of hosts 2 and 3 take over instance 1's streams;
4. ``restored``: the link up, no delay or loss. Instance 1 comes back, sees the others and
   hands back what is not its own; the phase lasts ``phase_s`` after every instance runs
   its own streams' sessions again (or ``settle_s``, whichever comes first).

The report, per phase: frames sent, answered, answered twice (two owners at once); the
median capture-to-result latency; the longest time any stream went without a result; when
the station was linked to another router; and at the end the sessions each instance runs and
what was answered twice after the fleet settled (one owner per stream: none).
"""

from __future__ import annotations

import itertools
import json
import signal
import statistics
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from .driver import balanced_streams
from .netlab import NetLab
from .procs import Program, RouterProcess, ServiceProcess
from .waiting import wait_until

PORT = 7447
HOSTS = ("h1", "h2", "h3")
PHASES = ("clean", "slow", "cut", "restored")


def instance_id(host: str) -> str:
    return f"inst-{host}"


def run(*, phase_s: float = 8.0, settle_s: float = 90.0, fps: float = 5.0,
        per_instance: int = 2, delay_ms: float = 20.0, loss: float = 0.01,
        lease_ms: int = 3000) -> dict[str, Any]:
    ids = [instance_id(h) for h in HOSTS]
    streams = balanced_streams(ids, per_instance)
    out_file = Path(tempfile.mkdtemp(prefix="arcf-netfleet-")) / "station.json"
    marks: dict[str, float] = {}
    with NetLab([*HOSTS, "st"]) as lab, ExitStack() as stack:
        def public(host: str) -> str:
            return f"tcp/{lab.address[host]}:{PORT}"

        local = f"tcp/127.0.0.1:{PORT}"
        routers, relays, instances = {}, {}, {}
        for i, host in enumerate(HOSTS):
            routers[host] = stack.enter_context(RouterProcess(
                local, [public(h) for h in HOSTS[:i]], prefix=lab.prefix(host),
                lease_ms=lease_ms))
            relays[host] = stack.enter_context(Program(
                "arcf.loadtools.relay",
                ["--listen", f"{lab.address[host]}:{PORT}", "--to", f"127.0.0.1:{PORT}",
                 "--delay-ms", f"{delay_ms:g}"], quiet=True, env=None,
                prefix=lab.prefix(host)))
        for host in HOSTS:
            others = [arg for h in HOSTS if h != host for arg in ("--connect", public(h))]
            instances[host] = stack.enter_context(ServiceProcess(
                "--instance-id", instance_id(host), *others, "--lease-ms", str(lease_ms),
                connect=local, workers=1, prefix=lab.prefix(host),
                metrics_host=lab.address[host]))
        station = stack.enter_context(Program(
            "arcf.loadtools.station",
            [*(arg for h in HOSTS for arg in ("--connect", public(h))),
             "--streams", ",".join(streams), "--fps", f"{fps:g}",
             "--frames", str(int(fps * (4 * phase_s + settle_s + 60))),
             "--lease-ms", str(lease_ms), "--out", str(out_file)],
            quiet=True, env=None, prefix=lab.prefix("st")))

        def sessions() -> dict[str, float]:
            return {h: svc.metric("arcf_active_sessions") for h, svc in instances.items()}

        def settled() -> bool:
            try:
                return all(v == per_instance for v in sessions().values())
            except OSError:  # a host cut off: its metrics do not answer
                return False

        wait_until(settled, timeout=120, what="every instance running its own streams")
        marks["clean"] = time.monotonic()
        time.sleep(phase_s)
        marks["slow"] = time.monotonic()
        relays["h1"].proc.send_signal(signal.SIGUSR1)
        lab.lose("h1", loss)
        time.sleep(phase_s)
        marks["cut"] = time.monotonic()
        lab.cut("h1")
        time.sleep(phase_s)
        marks["restored"] = time.monotonic()
        lab.restore("h1")
        lab.lose("h1", 0.0)
        relays["h1"].proc.send_signal(signal.SIGUSR2)
        deadline = time.monotonic() + settle_s
        while time.monotonic() < deadline and not settled():
            time.sleep(0.2)
        marks["settled"] = time.monotonic()
        owners = sessions()
        time.sleep(phase_s)
        marks["end"] = time.monotonic()
        reconnects = {h: svc.metric("arcf_router_reconnects_total")
                      for h, svc in instances.items()}
        code = station.stop()
        if code != 0:
            raise RuntimeError(f"the station exited with {code}: {station.log()[-2000:]}")
        seen = json.loads(out_file.read_text())
    return report(seen, marks, owners, reconnects, streams)


def report(seen: dict[str, Any], marks: dict[str, float], owners: dict[str, float],
           reconnects: dict[str, float], streams: list[str]) -> dict[str, Any]:
    """Per phase: frames sent and answered, answered twice, the longest silence of a stream,
    the station's relinks; then who owned what once settled."""
    bounds = [(p, marks[p], marks[n]) for p, n in zip(PHASES, [*PHASES[1:], "end"],
                                                         strict=True)]
    phases = []
    for phase, t0, t1 in bounds:
        sent = answered = twice = 0
        silence = 0.0
        latencies: list[float] = []
        for name in streams:
            record = seen["streams"][name]
            sent_here = {seq for seq, t in record["sent"] if t0 <= t < t1}
            got = [r for r in record["received"] if r[1] in sent_here]
            seqs = [r[1] for r in got]
            sent += len(sent_here)
            answered += len(set(seqs))
            twice += len(seqs) - len(set(seqs))
            latencies += [r[5] for r in record["received"] if t0 <= r[0] < t1]
            times = [t0, *sorted(r[0] for r in record["received"] if t0 <= r[0] < t1), t1]
            silence = max(silence, max(b - a for a, b in itertools.pairwise(times)))
        relinks = [t - t0 for t, zids in seen["routers"] if t0 <= t < t1 and zids]
        phases.append({"phase": phase, "seconds": t1 - t0, "sent": sent, "answered": answered,
                       "answered_twice": twice, "longest_silence_s": silence,
                       "latency_p50_s": statistics.median(latencies) if latencies else None,
                       "station_relinked_after_s": relinks[0] if relinks else None})
    late_twice = 0
    for name in streams:
        late = [r[1] for r in seen["streams"][name]["received"] if r[0] >= marks["settled"]]
        late_twice += len(late) - len(set(late))
    return {"phases": phases, "settle_s": marks["settled"] - marks["restored"],
            "sessions_when_settled": owners, "answered_twice_after_settling": late_twice,
            "reconnects": reconnects, "streams": streams}

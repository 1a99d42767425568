"""Scale-out on loopback: three service instances and a Zenoh router, as separate processes.

Streams spread over all three; a SIGKILLed instance's streams are resumed by the survivors from
their last published box, and no other stream notices; a fourth instance takes over its share
without interrupting the rest; a frozen instance (SIGSTOP) is found out by the Zenoh lease.

The waits have generous deadlines; how long a failover takes is benchmarks/scaleout.py's figure.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("zenoh")

from arcf.client import TrackingClient
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.driver import Clip, failover_fleet
from arcf.loadtools.ledger import Ledger
from arcf.loadtools.procs import RouterProcess, ServiceProcess, start_instances
from arcf.loadtools.waiting import wait_until
from arcf.service.cluster import owner

pytestmark = [pytest.mark.integration, pytest.mark.heavy,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

FPS = 5.0
#: the instances' Zenoh lease: long enough that a process the loaded machine stalls for a
#: second is not taken for dead (its streams would move, and back), short enough for the test
LEASE_S = 3.0
IDS = ["inst-a", "inst-b", "inst-c"]
#: a deadline to wait for a failover or a rebalancing, far above what either takes (the lease,
#: a few round trips); not a figure of the machine
DEADLINE_S = 60.0


def results_after(ledger: Ledger, names: list[str], t: float, n: int = 1) -> None:
    """Wait until every stream of ``names`` has ``n`` results that arrived after ``t``."""
    def ok() -> bool:
        return all(sum(r.t > t for r in list(ledger[name].received)) >= n for name in names)

    wait_until(ok, timeout=DEADLINE_S, what=f"{n} result(s) of each of {names} after {t:.1f}")


def unnoticed(ledger: Ledger, name: str, since: float) -> None:
    """Stream ``name`` went on as it was: not resumed elsewhere since ``since``, and every
    frame answered or counted as dropped, in order (a frame a stalled machine's queue sheds is
    counted; one lost in a move is not)."""
    assert ledger[name].first_with_status("resumed", since) is None, name
    counts = ledger[name].accounting()
    assert counts["unaccounted"] == 0 and counts["out_of_order"] == 0, (name, counts)


def pick_streams() -> list[str]:
    """Six stream ids, two per instance of three; at least two move to a fourth, and the
    victim (inst-b) owns two."""
    for start in range(0, 10000, 7):
        names = [f"cam-{start + k}" for k in range(6)]
        three = [owner(n, IDS) for n in names]
        four = [owner(n, [*IDS, "inst-d"]) for n in names]
        if all(three.count(i) == 2 for i in IDS) and four.count("inst-d") >= 2:
            return names
    raise AssertionError("no stream names found")


def test_instances_share_streams_fail_over_and_rebalance() -> None:
    seq = load_dataset("uav123_10fps", sequences=["truck4_1"])[0]
    streams = pick_streams()
    router = RouterProcess()
    extra = ("--lease-ms", str(int(LEASE_S * 1000)))
    instances = start_instances(IDS, router.endpoint, *extra)
    client = TrackingClient(connect=[router.endpoint])
    fleet = None
    newcomer = None
    try:
        status = client.status()
        assert sorted(status.instances) == IDS
        # bounded: 2 minutes at 5 fps
        fleet = failover_fleet(client, Clip.of(seq), streams, preset="bacf", fps=FPS,
                               frames=600)
        ledger = fleet.ledger
        results_after(ledger, streams, 0.0)

        # 1. spread: every stream tracked, two sessions on each instance
        for name in streams:
            assert ledger[name].received, f"no results for {name}"
        for i, svc in instances.items():
            wait_until(lambda svc=svc: svc.metric("arcf_active_sessions") == 2,
                       timeout=DEADLINE_S,
                       what=f"two active sessions on {i}")
        assert len(client.status().sessions) == 6  # any instance answers for all

        # 2. failover: SIGKILL inst-b; its streams resume elsewhere, the others never notice
        victim = [n for n in streams if owner(n, IDS) == "inst-b"]
        others = [n for n in streams if n not in victim]
        t_kill = time.monotonic()
        instances["inst-b"].proc.send_signal(signal.SIGKILL)
        instances["inst-b"].proc.wait(timeout=10)
        resumed_at = ledger.first_resumed(victim, t_kill, timeout=DEADLINE_S)
        assert sorted(resumed_at) == sorted(victim), "streams of the killed instance not resumed"
        failover_s = max(resumed_at.values()) - t_kill  # reported, not asserted
        for n in victim:  # five results from the new owner...
            results_after(ledger, [n], resumed_at[n], n=5)
        results_after(ledger, others, max(resumed_at.values()))  # ...and the others go on
        for n in others:
            unnoticed(ledger, n, 0.0)
        for n in victim:  # resumed from the last box, and tracking since
            after = [r for r in ledger[n].received if r.t > resumed_at[n]]
            assert len(after) >= 5 and all(r.status == "tracking" for r in after[1:])
        survivors = [i for i in IDS if i != "inst-b"]
        wait_until(lambda: sum(instances[i].metric("arcf_active_sessions")
                               for i in survivors) == 6, timeout=30,
                   what="the six sessions active on the survivors")
        assert sum(instances[i].metric("arcf_sessions_taken_over_total")
                   for i in survivors) == len(victim)
        # 3. a fourth instance takes over its share; the rest run on untouched
        t_join = time.monotonic()
        newcomer = ServiceProcess("--instance-id", "inst-d", *extra, connect=router.endpoint,
                                  workers=1)
        live = [*survivors, "inst-d"]
        moving = [n for n in streams if owner(n, live) == "inst-d"]
        staying = [n for n in streams if n not in moving]
        assert moving
        joined = ledger.first_resumed(moving, t_join, timeout=DEADLINE_S)
        assert set(joined) == set(moving)
        wait_until(lambda: newcomer.metric("arcf_active_sessions") == len(moving), timeout=30,
                   what="the moved sessions active on the newcomer")
        results_after(ledger, streams, max(joined.values()), n=3)  # every session goes on
        for n in staying:
            unnoticed(ledger, n, t_join)

        # 4. a hung instance (all its processes frozen) is detected by the Zenoh lease
        frozen = max(live, key=lambda i: sum(owner(n, live) == i for n in streams))
        stuck = [n for n in streams if owner(n, live) == frozen]
        procs = instances | {"inst-d": newcomer}
        pids = [procs[frozen].pid, *procs[frozen].workers]
        t_stop = time.monotonic()
        for pid in pids:
            os.kill(pid, signal.SIGSTOP)
        try:
            taken = ledger.first_resumed(stuck, t_stop, timeout=DEADLINE_S)
            assert set(taken) == set(stuck)
            hang_s = min(taken.values()) - t_stop  # the earliest takeover
            # not before the lease could expire (a lower bound: a slow machine is only later)
            assert hang_s >= LEASE_S * 0.5
        finally:
            for pid in pids:
                os.kill(pid, signal.SIGKILL)
                os.kill(pid, signal.SIGCONT)
            procs[frozen].proc.wait(timeout=10)
        print(f"failover {failover_s * 1e3:.0f} ms, hang detected in {hang_s:.1f} s")
    finally:
        if fleet is not None:
            fleet.pause()
        client.close()
        for svc in [*instances.values(), *([newcomer] if newcomer else [])]:
            if svc.proc.poll() is None:
                assert svc.stop() == 0
        router.stop()
        for svc in instances.values():  # no orphaned worker of the killed instance
            for pid in svc.workers:
                stat = Path(f"/proc/{pid}/stat")
                assert not stat.exists() or stat.read_text().rsplit(")", 1)[1].split()[0] == "Z"


def expired(r: Any) -> bool:
    """A session's last result, ended by its station's absence."""
    return r.status == "stopped" and r.code == "session_expired"


def test_a_vanished_stations_grace_outlives_the_instance_running_its_session() -> None:
    """A station vanishes, and the instance running its session dies during the grace: the
    instance that resumes the session gives the station a grace of its own, so the session
    still ends by the station's absence (not, a minute later, by idling), and says so."""
    clip = Clip.of(load_dataset("uav123_10fps", sequences=["wakeboard7"])[0], limit=40)
    ids = ["grace-a", "grace-b"]
    stream = next(n for n in (f"grace-{k}" for k in range(1000)) if owner(n, ids) == "grace-a")
    router = RouterProcess()
    # a grace long enough that the instance dies inside it however slowly this loop runs on
    # a loaded machine (the kill comes 1 s into it, by the clock, not by frames sent)
    instances = start_instances(ids, router.endpoint, "--lease-ms", "1500",
                                "--client-grace-s", "8", "--session-idle-s", "60")
    observer = TrackingClient(connect=[router.endpoint], tie_sessions=False)
    station = TrackingClient(connect=[router.endpoint])
    try:
        results: list = []
        sub = observer.results(stream, callback=results.append)
        station.start(stream, clip.box, preset="bacf", frame_seq=0)
        t0 = time.monotonic()
        seq, closed_at, killed_at = 0, None, None
        # frames keep coming (from the observer): nothing here idles (the idle limit is 60 s,
        # and the session produces results); a deadline of 50 s for the grace (8 s) to end it
        # (the dying instance's worker may say "stopped" too, for the instance that takes
        # over: only the grace's end ends the loop)
        while time.monotonic() - t0 < 50 and not any(expired(r) for r in results):
            observer.publish_frame(stream, data=clip.frames[seq % len(clip)], seq=seq)
            seq += 1
            if seq == 10:
                station.close()  # the station is gone: its grace starts
                closed_at = time.monotonic()
            if (killed_at is None and closed_at is not None
                    and time.monotonic() - closed_at >= 1.0):
                # 1 s into the grace, the instance running the session dies
                instances["grace-a"].proc.send_signal(signal.SIGKILL)
                instances["grace-a"].proc.wait(timeout=10)
                killed_at = time.monotonic()
            time.sleep(0.1)  # the stimulus: a 10 fps camera
        sub.close()
        statuses = [r.status.value for r in results]
        assert "resumed" in statuses, statuses  # the survivor took the session over...
        (stopped,) = [r for r in results if expired(r)]  # ...and ended it
        assert station.client_id in stopped.message
        # by the station's absence, after the instance died (not by idling: frames flowed)
        assert killed_at is not None and statuses.index("resumed") < results.index(stopped)
    finally:
        observer.close()
        for svc in instances.values():
            if svc.proc.poll() is None:
                assert svc.stop() == 0
        router.stop()

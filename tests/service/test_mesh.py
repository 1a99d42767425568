"""A fleet without a single router: two Zenoh routers joined as a mesh, an instance and a
station's sessions spread over them, one router SIGKILLed.

What was attached to the dead router (the station, one instance) links to the other router
of its endpoint list by itself; the sessions of the instance that lost its router resume
(from their last box), the others go on, the instance counts the reconnect, and once the
fleet has settled each stream has exactly one owner again (no result answered twice). How
long the switch takes is ``benchmarks/mesh_failover.py``'s figure, not this test's.
"""

from __future__ import annotations

import signal
import time

import pytest

pytest.importorskip("zenoh")

from arcf.client import TrackingClient
from arcf.data import data_root
from arcf.eval import load_dataset
from arcf.loadtools.driver import Clip, balanced_streams, failover_fleet
from arcf.loadtools.ledger import Ledger
from arcf.loadtools.procs import RouterProcess, ServiceProcess, free_port
from arcf.loadtools.waiting import wait_until
from arcf.service.cluster import owner
from arcf.service.scrape import by_label, fetch

pytestmark = [pytest.mark.integration, pytest.mark.heavy,
              pytest.mark.skipif(not (data_root() / "uav123_10fps").is_dir(),
                                 reason="needs ../shared/data")]

FPS = 5.0
LEASE_MS = "3000"
IDS = ["inst-a", "inst-b"]
#: far above what a switch takes (milliseconds); not a figure of the machine
DEADLINE_S = 60.0


def results_after(ledger: Ledger, names: list[str], t: float, n: int) -> None:
    def ok() -> bool:
        return all(sum(r.t > t for r in list(ledger[name].received)) >= n for name in names)

    wait_until(ok, timeout=DEADLINE_S, what=f"{n} result(s) of each of {names} after {t:.1f}")


def test_a_dead_router_loses_only_what_was_attached_to_it() -> None:
    seq = load_dataset("uav123_10fps", sequences=["truck4_1"])[0]
    streams = balanced_streams(IDS, 2)
    a_end, b_end = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    # each router connects to the other: whichever starts first, they join
    router_a = RouterProcess(a_end, [b_end], metrics=True)
    router_b = RouterProcess(b_end, [a_end], metrics=True)
    instances: dict[str, ServiceProcess] = {}
    client = fleet = None
    try:
        # each instance on its own host's router first, the other as its fallback
        for iid, (first, second) in zip(IDS, [(a_end, b_end), (b_end, a_end)], strict=True):
            instances[iid] = ServiceProcess("--instance-id", iid, "--connect", second,
                                            "--lease-ms", LEASE_MS, connect=first, workers=1)
        client = TrackingClient(connect=[a_end, b_end])  # the station on router A
        wait_until(lambda: sorted(client.status().instances) == IDS, timeout=DEADLINE_S,
                   what="both instances seen through the mesh")
        # bounded: 2 minutes at 5 fps
        fleet = failover_fleet(client, Clip.of(seq), streams, preset="bacf", fps=FPS,
                               frames=600)
        ledger = fleet.ledger
        results_after(ledger, streams, 0.0, n=1)
        for iid, svc in instances.items():
            wait_until(lambda svc=svc: svc.metric("arcf_active_sessions") == 2,
                       timeout=DEADLINE_S, what=f"two sessions on {iid}")
            assert svc.metric("arcf_zenoh_routers") == 1
        assert sum(svc.metric("arcf_router_reconnects_total")
                   for svc in instances.values()) == 0

        # each router's own metrics: the other router, and its clients (station, instances
        # and their workers)
        linked = {name: by_label(fetch(r.metrics_url), "arcf_router_sessions", "whatami")
                  for name, r in (("a", router_a), ("b", router_b)) if r.metrics_url}
        assert linked["a"]["router"] == linked["b"]["router"] == 1
        assert linked["a"]["client"] == 3 and linked["b"]["client"] == 2  # station on A

        def station_routers() -> set[str]:
            assert client is not None
            return {str(z) for z in client.session.info.routers_zid()}

        on_a = station_routers()
        assert len(on_a) == 1  # a client links to one router: the first of its list

        lost = [n for n in streams if owner(n, IDS) == "inst-a"]
        t_kill = time.monotonic()
        router_a.proc.send_signal(signal.SIGKILL)
        router_a.proc.wait(timeout=10)

        # the station and inst-a relink to router B; every stream goes on, inst-a's resumed
        wait_until(lambda: len(station_routers() - on_a) == 1, timeout=DEADLINE_S,
                   what="the station linked to router B")
        results_after(ledger, streams, t_kill, n=5)
        resumed = ledger.first_resumed(lost, t_kill, timeout=DEADLINE_S)
        assert sorted(resumed) == sorted(lost)
        wait_until(lambda: instances["inst-a"].metric("arcf_router_reconnects_total") == 1,
                   timeout=DEADLINE_S, what="inst-a's reconnect counted")
        assert instances["inst-b"].metric("arcf_router_reconnects_total") == 0
        for iid, svc in instances.items():
            assert svc.metric("arcf_zenoh_routers") == 1, iid
            wait_until(lambda svc=svc: svc.metric("arcf_active_sessions") == 2,
                       timeout=DEADLINE_S, what=f"two sessions on {iid} again")
        assert sorted(client.status().instances) == IDS
        assert router_b.metrics_url is not None
        wait_until(lambda: by_label(fetch(router_b.metrics_url), "arcf_router_sessions",
                                    "whatami") == {"client": 5, "peer": 0, "router": 0},
                   timeout=DEADLINE_S, what="everything on router B, alone")

        # settled: one owner per stream, every frame answered once, in order
        t_settled = time.monotonic()
        results_after(ledger, streams, t_settled, n=10)
        for name in streams:
            after = [r for r in list(ledger[name].received) if r.t > t_settled]
            seqs = [r.frame_seq for r in after]
            assert seqs == sorted(set(seqs)), (name, seqs)
            assert {r.status for r in after} == {"tracking"}, name
    finally:
        if fleet is not None:
            fleet.pause()
        if client is not None:
            client.close()
        codes = {iid: svc.stop() for iid, svc in instances.items()}
        for router in (router_a, router_b):
            router.stop()
        assert codes == dict.fromkeys(instances, 0)  # clean shutdowns

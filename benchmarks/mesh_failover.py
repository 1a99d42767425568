"""A router mesh losing a router: how long the streams attached to it stop, on loopback.

    python benchmarks/mesh_failover.py                  # 5 trials, about 3 minutes
    python benchmarks/mesh_failover.py --trials 3 --json mesh.json

Each trial builds the fleet docs/deploy-a-fleet.md describes, shrunk to two hosts: two Zenoh
routers (``arcf-router``) joined as a mesh, each with a service instance that connects to
its own router first and to the other as its fallback (one worker each), and a station whose
endpoint list names both routers, linked to router A. Four streams of a real sequence at
``--fps``, two owned by each instance. After ``--warm-s`` seconds router A is SIGKILLed:
the station and instance a relink to router B by themselves, instance a's streams resume
(its workers were cut off too, and fence themselves), instance b's go on.

Measured per trial: when the station was linked to router B again; per stream, the kill to
the first result after it (instance a's: the first ``resumed`` one); frames sent in the
trial that never got a result; frames answered twice (two owners at once, during the
switch); and once settled, that each instance runs two sessions and no frame of the last
``--settle-s`` seconds was answered twice (one owner per stream).
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path
from typing import Any

from _common import parser, spread, write_trials  # beside this script

from arcf.client import TrackingClient
from arcf.eval import load_dataset
from arcf.loadtools.driver import Clip, balanced_streams, failover_fleet
from arcf.loadtools.procs import RouterProcess, ServiceProcess, free_port
from arcf.loadtools.system import machine
from arcf.loadtools.waiting import wait_until
from arcf.service.cluster import owner

IDS = ["inst-a", "inst-b"]


def trial(clip: Clip, fps: float, warm_s: float, watch_s: float, settle_s: float
          ) -> dict[str, Any]:
    a_end, b_end = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    routers = [RouterProcess(a_end, [b_end]), RouterProcess(b_end, [a_end])]
    instances = {
        iid: ServiceProcess("--instance-id", iid, "--connect", second, "--lease-ms", "3000",
                            connect=first, workers=1)
        for iid, (first, second) in zip(IDS, [(a_end, b_end), (b_end, a_end)], strict=True)}
    client = TrackingClient(connect=[a_end, b_end])
    names = balanced_streams(IDS, 2)
    frames = int(fps * (warm_s + watch_s + settle_s + 10))
    fleet = failover_fleet(client, clip, names, preset="bacf", fps=fps, frames=frames)
    try:
        ledger = fleet.ledger
        wait_until(lambda: all(ledger[n].received for n in names), timeout=60,
                   what="every stream answered")
        time.sleep(warm_s)
        on_a = {str(z) for z in client.session.info.routers_zid()}
        t_kill = time.monotonic()
        routers[0].proc.send_signal(signal.SIGKILL)
        relinked = None
        while time.monotonic() - t_kill < watch_s:
            now = {str(z) for z in client.session.info.routers_zid()}
            if relinked is None and now and now != on_a:
                relinked = time.monotonic() - t_kill
            time.sleep(0.005)
        lost = [n for n in names if owner(n, IDS) == "inst-a"]
        outage = {}
        for n in names:
            after = [r for r in list(ledger[n].received) if r.t > t_kill
                     and (n not in lost or r.status == "resumed")]
            outage[n] = after[0].t - t_kill if after else float("inf")
        wait_until(lambda: all(svc.metric("arcf_active_sessions") == 2
                               for svc in instances.values()), timeout=60,
                   what="two sessions on each instance")
        t_settled = time.monotonic()
        time.sleep(settle_s)
        fleet.pause()
        twice = settled_twice = unanswered = 0
        for n in names:
            received = list(ledger[n].received)
            seqs = [r.frame_seq for r in received]
            twice += len(seqs) - len(set(seqs))
            late = [r.frame_seq for r in received if r.t > t_settled]
            settled_twice += len(late) - len(set(late))
            sent = {seq for seq, _ in ledger[n].sent}
            unanswered += len(sent - set(seqs) - {max(sent)})  # the last may be in flight
        return {
            "station_relinked_s": relinked,
            "outage_s": {n: outage[n] for n in names},
            "lost_instance_streams": lost,
            "frames_unanswered": unanswered,
            "frames_answered_twice": twice,
            "answered_twice_after_settling": settled_twice,
            "reconnects": {i: svc.metric("arcf_router_reconnects_total")
                           for i, svc in instances.items()},
            "takeovers": {i: svc.metric("arcf_sessions_taken_over_total")
                          for i, svc in instances.items()},
        }
    finally:
        fleet.pause()
        client.close()
        for svc in instances.values():
            svc.stop()
        for router in routers:
            router.stop()


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__, fps=10.0)
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--sequence", default="truck4_1", help="a UAV123@10fps sequence")
    ap.add_argument("--warm-s", type=float, default=4.0, help="tracking before the kill")
    ap.add_argument("--watch-s", type=float, default=4.0, help="watched after the kill")
    ap.add_argument("--settle-s", type=float, default=3.0,
                    help="watched once each instance runs two sessions again")
    ap.add_argument("--json", type=Path, help="write every trial's figures here")
    args = ap.parse_args(argv)
    clip = Clip.of(load_dataset("uav123_10fps", sequences=[args.sequence])[0])
    trials = [trial(clip, args.fps, args.warm_s, args.watch_s, args.settle_s)
              for _ in range(args.trials)]
    m = machine()
    print(f"`python benchmarks/mesh_failover.py {' '.join(argv or sys.argv[1:])}`"
          .replace(" `", "`"))
    print(f"{time.strftime('%Y-%m-%d')}, {m['cpu']} ({m['nproc']} cores), {m['software']}; "
          f"{args.trials} trials, 4 streams at {args.fps:g} fps, router A SIGKILLed\n")

    def ms(values: list[float]) -> str:
        return spread([1e3 * v for v in values], unit=" ms")

    relinked = [t["station_relinked_s"] for t in trials if t["station_relinked_s"] is not None]
    moved = [t["outage_s"][n] for t in trials for n in t["lost_instance_streams"]]
    stayed = [v for t in trials for n, v in t["outage_s"].items()
              if n not in t["lost_instance_streams"]]
    print("| measured | median (min–max) over trials and streams |")
    print("| --- | --- |")
    print(f"| station linked to router B, after the kill | {ms(relinked)} "
          f"({len(relinked)}/{len(trials)} trials) |")
    print(f"| instance a's streams: kill to the first `resumed` result | {ms(moved)} |")
    print(f"| instance b's streams: kill to the next result | {ms(stayed)} |")
    for key, label in (("frames_unanswered", "frames never answered, per trial"),
                       ("frames_answered_twice", "frames answered twice, per trial"),
                       ("answered_twice_after_settling",
                        "frames answered twice once settled, per trial")):
        print(f"| {label} | {spread([t[key] for t in trials], '{:g}')} |")
    print(f"| instance a's reconnects counted | "
          f"{sorted(t['reconnects']['inst-a'] for t in trials)} |")
    write_trials(args.json, m, trials)
    return 0


if __name__ == "__main__":
    sys.exit(main())

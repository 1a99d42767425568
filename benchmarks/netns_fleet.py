"""A fleet over real links: what each phase of a link's faults costs the streams.

    python benchmarks/netns_fleet.py                    # 3 trials, about 4 minutes (root)

Three hosts as Linux network namespaces on a bridge, each with its Zenoh router (a mesh) and
one service instance (one worker), a station in a fourth namespace streaming 6 BACF streams
of truck4_1 at 5 fps, linked to host 1's router. Host 1's link goes through four phases of
``--phase-s`` seconds: clean; slow and lossy (``--delay-ms`` each way through a user-space
relay, since this kernel has no ``sch_netem``, and ``--loss`` of the packets dropped at
random each way by the kernel); cut (a partition); restored, until every instance runs its
own streams again and ``--phase-s`` more (:mod:`arcf.loadtools.netfleet`). Zenoh's lease is
3000 ms everywhere; the station tries a router that does not answer for 1 s before the next.
"""

from __future__ import annotations

import sys
from pathlib import Path

from _common import header, parser, spread, write_trials  # beside this script

from arcf.loadtools import netfleet
from arcf.loadtools.netlab import unavailable
from arcf.loadtools.system import machine


def main(argv: list[str] | None = None) -> int:
    ap = parser(__doc__, fps=5.0)
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--phase-s", type=float, default=10.0)
    ap.add_argument("--delay-ms", type=float, default=20.0)
    ap.add_argument("--loss", type=float, default=0.01)
    ap.add_argument("--json", type=Path, help="write every trial's report here")
    args = ap.parse_args(argv)
    why = unavailable()
    if why:
        raise SystemExit(f"netns_fleet: {why}")
    trials = [netfleet.run(phase_s=args.phase_s, fps=args.fps, delay_ms=args.delay_ms,
                           loss=args.loss) for _ in range(args.trials)]
    m = machine()
    header("netns_fleet.py", argv, m, (
        f"{args.trials} trials, 6 streams at {args.fps:g} fps, phases of {args.phase_s:g} s, "
        f"slow = {args.delay_ms:g} ms each way and {100 * args.loss:g} % loss each way"))

    print("| phase | frames answered | answered twice | latency p50 (ms) "
          "| longest silence of a stream (s) | station relinked after (s) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for k, phase in enumerate(netfleet.PHASES):
        rows = [t["phases"][k] for t in trials]
        share = [100 * r["answered"] / max(r["sent"], 1) for r in rows]
        relinks = [r["station_relinked_after_s"] for r in rows
                   if r["station_relinked_after_s"] is not None]
        print(f"| {phase} | {spread(share, '{:.1f}')} % | "
              f"{spread([r['answered_twice'] for r in rows])} | "
              f"{spread([1e3 * r['latency_p50_s'] for r in rows if r['latency_p50_s']])} | "
              f"{spread([r['longest_silence_s'] for r in rows], '{:.2f}')} | "
              f"{spread(relinks, '{:.2f}')} ({len(relinks)}/{len(rows)}) |")
    settle = [t["settle_s"] for t in trials]
    one_owner = sum(set(t["sessions_when_settled"].values()) == {2.0} for t in trials)
    print(f"\nAfter the link was restored: every instance ran its own two streams again after "
          f"{spread(settle, '{:.1f}')} s ({one_owner}/{len(trials)} trials); frames answered "
          f"twice after that: {sum(t['answered_twice_after_settling'] for t in trials)}.")
    write_trials(args.json, m, trials)
    return 0


if __name__ == "__main__":
    sys.exit(main())

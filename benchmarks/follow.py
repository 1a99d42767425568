"""The follow loop closed in simulated time: a virtual gimbal camera (640x360 of a shared
sequence's 1280x720 pictures, which span 90 degrees) starts with the target a quarter of the
view right of the centre and a fifth above it; the tracker runs on its views and the follow
controller steers it, at 10 and 30 Hz. Printed per sequence: when the target's true centre
first stays within 10 % of the view's centre, its largest offset after 3 s, the largest
swing of the tracker's box past the centre while settling, and the frames not ``tracking``.

    python benchmarks/follow.py                          # about 5 minutes
    python benchmarks/follow.py --sequences boat1 --preset arcf-hc
"""

from __future__ import annotations

import datetime
import sys
from collections.abc import Sequence

import numpy as np
from _common import parser  # beside this script

from arcf.eval import load_dataset
from arcf.eval.environment import describe
from arcf.loadtools.gimbalsim import run_follow


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser(__doc__, preset="arcf-h")
    ap.add_argument("--sequences", default="boat1,truck4_1,truck4_2,wakeboard7,wakeboard10")
    ap.add_argument("--rates", default="10,30")
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args(argv)
    print(f"# python benchmarks/follow.py {' '.join(argv or sys.argv[1:])}")
    print(f"# {datetime.date.today()}, {describe()}; simulated time (the figures do not depend "
          "on the machine's speed)")
    print("\n| sequence | rate | settled within 10 % at | largest offset after 3 s | "
          "swing past the centre | frames not tracking |\n| --- | --- | --- | --- | --- | --- |")
    for name in args.sequences.split(","):
        (seq,) = load_dataset("uav123_10fps", sequences=[name])
        for rate in (float(r) for r in args.rates.split(",")):
            run = run_follow(seq, rate_hz=rate, preset=args.preset, seconds=args.seconds)
            off, t = run.offsets(), np.array(run.t)
            inside = np.abs(off).max(axis=1) < 0.10
            settle = next((t[k] for k in range(len(t)) if inside[k:].all()), None)
            after = np.abs(off[t >= 3.0]).max()
            seen = np.array(run.seen)[t < 3.0]
            swing = max(0.0, float((-seen[:, 0]).max()), float(seen[:, 1].max()))
            lost = sum(s not in ("tracking", "initialized") for s in run.state)
            print(f"| {name} | {rate:g} Hz | {'never' if settle is None else f'{settle:.1f} s'}"
                  f" | {after:.3f} | {swing:.3f} | {lost} of {len(run.state)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""How much the last bits of fHOG's SSE arithmetic decide whether a run follows the release.

The release's gradient code (Piotr's toolbox ``gradMag``, SSE) takes a pixel's orientation from
``(int)(gx * rsqrt(m2) * 10000)`` and its magnitude from ``rcp(rsqrt(m2))``, where ``rsqrt`` and
``rcp`` are the CPU's ~12-bit approximations, whose last bits differ between vendors. Release
mode (``arcf.RELEASE_COMPATIBLE``) replays the instructions of the AMD EPYC that traced the
release, from the table shipped with the package (``fhog_sse_table="amd-epyc"``). A pixel
whose orientation index sits next to a bin boundary lands in the bin those bits say.

This script measures how much that matters. For each run (tracker, sequence) it replays
release mode three ways, changing nothing but fHOG's instructions:

* **table**: ``RELEASE_COMPATIBLE`` as shipped (the EPYC's measured instructions);
* **model**: ``RELEASE_COMPATIBLE`` with the 13-bit model of them instead
  (``fhog_sse_table=None``, what ``fhog(arithmetic="release")`` computes);
* **variants**: the EPYC's table with every ``rsqrt`` bucket moved by a random -1, 0 or +1
  unit in its last bit (``2^11`` in the float32 pattern), written as table files and replayed
  through the same preset option: instructions as plausible as the EPYC's, but not its.

It prints, per run, the first frame whose centre differs from the release's box by more than
0.5 px for each, and how many runs match the release (mean centre distance <= 0.5 px). If a
divergence moves with the variants, the bits decide it; a divergence that no variant moves has
another cause (e.g. Newton's method at a chaotic frame).

    python benchmarks/arithmetic_sensitivity.py                       # the runs that differ
    python benchmarks/arithmetic_sensitivity.py --runs arcf-h/boat1 --variants 30
    python benchmarks/arithmetic_sensitivity.py --all --variants 4    # all 27 runs
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from arcf.data import data_root
from arcf.eval import load_dataset, read_results
from arcf.eval.metrics import centers
from arcf.features.sse import load_sse_tables
from arcf.loadtools.system import machine

SEQUENCES = {
    "boat1": "uav123_10fps", "truck4_1": "uav123_10fps", "truck4_2": "uav123_10fps",
    "wakeboard7": "uav123_10fps", "wakeboard10": "uav123_10fps", "Animal3": "dtb70",
    "BMX3": "dtb70", "MountainBike6": "dtb70", "S0310": "uavdt",
}
RELEASE_NAMES = {"arcf-h": "ARCF-H", "arcf-hc": "ARCF-HC", "bacf": "BACF"}
#: The runs whose boxes differ from the release's in release mode (docs/benchmarks.md,
#: "Fidelity"): the default subject.
DIFFERING = ("arcf-h/truck4_2", "arcf-h/BMX3")
MATCH_PX = 0.5
TABLE, MODEL = "table", "model"
#: One unit in the last bit of the EPYC's rsqrt results (they carry 12 fraction bits).
RSQRT_UNIT = 1 << 11


def write_variant(seed: int, folder: Path) -> Path:
    """The EPYC's table with each rsqrt bucket moved by ``-1``, ``0`` or ``+1`` last-bit units
    (random, from ``seed``), as a table file the preset option reads."""
    epyc = load_sse_tables("amd-epyc")
    offsets = np.random.default_rng(seed).integers(-1, 2, epyc.rsqrt.size)
    rsqrt = (epyc.rsqrt.astype(np.int64) + offsets * RSQRT_UNIT).astype(np.uint32)
    path = folder / f"variant_{seed}.txt"
    lines = [f"# cpu: variant {seed} of {epyc.cpu}"]
    lines += [f"rsqrt {k} {v:08x}" for k, v in enumerate(rsqrt)]
    lines += [f"rcp {k} {v:08x}" for k, v in enumerate(epyc.rcp)]
    path.write_text("\n".join(lines) + "\n")
    return path


def replay(job: tuple[str, str, str, str | None]) -> tuple[str, str, str, int | None, float, int]:
    """A whole release-mode run: first frame > 0.5 px from the release's box, mean distance."""
    preset, sequence, label, table = job
    import cv2

    import arcf

    cv2.setNumThreads(1)
    (seq,) = load_dataset(SEQUENCES[sequence], sequences=[sequence])
    ref = read_results(data_root() / "reference_release" / "boxes" / RELEASE_NAMES[preset]
                       / f"{sequence}.txt")
    tracker = arcf.create_tracker(preset, **{**arcf.RELEASE_COMPATIBLE, "fhog_sse_table": table})
    boxes = arcf.run_sequence(tracker, (seq.read_frame(i) for i in range(len(seq))),
                              seq.init_box).boxes
    d = np.linalg.norm(centers(boxes) - centers(ref[: len(boxes)]), axis=1)
    over = np.flatnonzero(d > MATCH_PX)
    first = int(over[0]) + 1 if over.size else None
    return preset, sequence, label, first, float(d.mean()), len(seq)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", help="comma-separated preset/sequence (default: the differing runs)")
    ap.add_argument("--all", action="store_true", help="all 27 (preset, sequence) runs")
    ap.add_argument("--variants", type=int, default=12, help="random variants per run")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    if args.all:
        runs = [f"{p}/{s}" for p in RELEASE_NAMES for s in SEQUENCES]
    else:
        runs = args.runs.split(",") if args.runs else list(DIFFERING)
    seeds = [str(s) for s in range(args.variants)]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tables: dict[str, str | None] = {TABLE: "amd-epyc", MODEL: None}
        tables.update({s: str(write_variant(int(s), Path(tmp))) for s in seeds})
        jobs = [(*r.split("/"), label, table) for r in runs for label, table in tables.items()]
        with ProcessPoolExecutor(args.workers) as pool:
            results = list(pool.map(replay, jobs))
    first: dict[tuple[str, str], dict[str, int | None]] = {}
    mean: dict[tuple[str, str], dict[str, float]] = {}
    lengths: dict[tuple[str, str], int] = {}
    for preset, sequence, label, frame, dist, n in results:
        first.setdefault((preset, sequence), {})[label] = frame
        mean.setdefault((preset, sequence), {})[label] = dist
        lengths[(preset, sequence)] = n

    def show(f: int | None) -> str:
        return "–" if f is None else str(f)

    def rank(f: int | None, n: int) -> int:
        return n + 1 if f is None else f

    host = machine()
    print(f"`python benchmarks/arithmetic_sensitivity.py {' '.join(sys.argv[1:])}`, "
          f"{time.strftime('%Y-%m-%d')}, {host['cpu']}, {host['nproc']} cores, "
          f"{host['software']}\n")
    print(f"First frame more than {MATCH_PX} px from the release's box ('–': none); "
          f"{args.variants} random variants of the EPYC's rsqrt table per run\n")
    print("| run | frames | table (shipped) | 13-bit model | variants, sorted | "
          "variants later than the table |")
    print("| --- | --- | --- | --- | --- | --- |")
    for run, frames in first.items():
        n = lengths[run]
        key = [rank(frames[s], n) for s in seeds]
        later = sum(k > rank(frames[TABLE], n) for k in key)
        ordered = ", ".join(show(frames[seeds[i]]) for i in np.argsort(key, kind="stable"))
        print(f"| {run[0]} {run[1]} | {n} | {show(frames[TABLE])} | {show(frames[MODEL])} | "
              f"{ordered} | {later} of {args.variants} |")
    matches = {label: sum(mean[r][label] <= MATCH_PX for r in mean) for label in tables}
    print(f"\nRuns matching the release (mean centre distance <= {MATCH_PX} px), of {len(mean)}: "
          f"table {matches[TABLE]}; model {matches[MODEL]}; variants "
          + ", ".join(str(matches[s]) for s in seeds))
    print(f"\n{len(jobs)} runs in {time.perf_counter() - t0:.0f} s, {args.workers} processes")
    return 0


if __name__ == "__main__":
    sys.exit(main())

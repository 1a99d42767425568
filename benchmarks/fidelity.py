"""Fidelity benchmark: our trackers next to the authors' own boxes on the real sequences.

Runs one-pass evaluation of ``arcf-hc``, ``arcf-h`` (both aberrance formulations) and ``bacf`` on
every sequence present under the data root (UAV123@10fps, DTB70, UAVDT layouts), scores them with
the official toolkit's convention, and prints a Markdown report comparing them with the authors'
published boxes for the same tracker on the same sequences: precision@20 and AUC, the mean centre
distance between our boxes and theirs, and the release-form map difference next to the published
``map_diff`` files (UAV123@10fps).

    python benchmarks/fidelity.py                 # all configurations, 2 processes
    python benchmarks/fidelity.py --jobs 1 --configs arcf-h:paper

Runs are cached under ``--out`` (default ``results/fidelity``), so a rerun only scores; pass
``--fresh`` to recompute.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from arcf.data import data_root
from arcf.eval import load_dataset, read_results, score_sequence, write_results
from arcf.eval.metrics import centers
from arcf.eval.runner import DATASET_FOLDERS

DATASETS = DATASET_FOLDERS  # our dataset names -> published-results folder names
CONFIGS = {
    "arcf-hc:paper": ("arcf-hc", {"aberrance": "paper"}, "ARCF-HC"),
    "arcf-hc:release": ("arcf-hc", {"aberrance": "release"}, "ARCF-HC"),
    "arcf-h:paper": ("arcf-h", {"aberrance": "paper"}, "ARCF-H"),
    "arcf-h:release": ("arcf-h", {"aberrance": "release"}, "ARCF-H"),
    "bacf": ("bacf", {}, "BACF"),
}


def _run_one(job: tuple[str, str, str, str, str]) -> tuple[str, str, str, float, int]:
    config, dataset, seq_name, root, out = job
    import cv2

    import arcf
    from arcf.run import run_sequence

    cv2.setNumThreads(1)
    preset, overrides, _ = CONFIGS[config]
    (seq,) = load_dataset(dataset, root=Path(root) / dataset, sequences=[seq_name])
    frames = [seq.read_frame(i) for i in range(len(seq))]
    tracker = arcf.create_tracker(preset, **overrides)
    run = run_sequence(tracker, frames, seq.init_box)
    target = Path(out) / config / DATASETS[dataset]
    target.mkdir(parents=True, exist_ok=True)
    np.savetxt(
        target / f"{seq_name}_map_diff.txt",
        np.array([[r.aberrance, r.aberrance_release] for r in run.results]),
        fmt="%.7f",
        delimiter=",",
    )
    write_results(target / f"{seq_name}.txt", run.boxes)  # written last: marks the run done
    return config, dataset, seq_name, run.fps, len(frames)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=data_root())
    ap.add_argument("--out", type=Path, default=Path("results/fidelity"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--fresh", action="store_true")
    args = ap.parse_args()
    configs = [c for c in args.configs.split(",") if c]
    for c in configs:
        if c not in CONFIGS:
            ap.error(f"unknown config {c!r}; choose from {', '.join(CONFIGS)}")

    sequences: dict[str, list[str]] = {}
    for ds in DATASETS:
        try:
            sequences[ds] = [s.name for s in load_dataset(ds, root=args.data / ds)]
        except Exception as exc:  # a dataset that is absent locally is simply skipped
            print(f"# skipping {ds}: {exc}", file=sys.stderr)
    jobs = [
        (c, ds, s, str(args.data), str(args.out))
        for c in configs
        for ds, names in sequences.items()
        for s in names
        if args.fresh or not (args.out / c / DATASETS[ds] / f"{s}.txt").exists()
    ]
    t0 = time.time()
    fps: dict[tuple[str, str], float] = {}
    if jobs:
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            for i, (c, _ds, s, f, n) in enumerate(pool.map(_run_one, jobs), 1):
                fps[(c, s)] = f
                print(f"# [{i}/{len(jobs)}] {c} {s}: {n} frames, {f:.1f} FPS "
                      f"({time.time() - t0:.0f} s)", file=sys.stderr)

    pub_root = args.data / "published_results"
    print(f"Data root: `{args.data}`; convention: toolkit (OTB/UAV123 MATLAB); "
          f"{sum(len(v) for v in sequences.values())} sequences.\n")
    print("| configuration | ours P@20 | authors' P@20 | ours AUC | authors' AUC "
          "| mean centre distance to authors' boxes (px) |")
    print("| --- | --- | --- | --- | --- | --- |")
    per_seq: dict[str, dict[str, float]] = {}
    for c in configs:
        _, _, pub_name = CONFIGS[c]
        ours_p, ours_a, pub_p, pub_a, dists = [], [], [], [], []
        for ds, names in sequences.items():
            for s in names:
                gt = read_results(pub_root / DATASETS[ds] / "groundtruth" / f"{s}.txt")
                mine = read_results(args.out / c / DATASETS[ds] / f"{s}.txt")
                theirs = read_results(pub_root / DATASETS[ds] / pub_name / f"{s}.txt")
                a, b = score_sequence(mine, gt), score_sequence(theirs, gt)
                ours_p.append(a.precision20)
                ours_a.append(a.auc)
                pub_p.append(b.precision20)
                pub_a.append(b.auc)
                n = min(len(mine), len(theirs))
                d = float(np.nanmean(np.linalg.norm(centers(mine[:n]) - centers(theirs[:n]),
                                                    axis=1)))
                dists.append(d)
                per_seq.setdefault(s, {})[c] = d
        print(f"| {c} | {np.mean(ours_p):.3f} | {np.mean(pub_p):.3f} | {np.mean(ours_a):.3f} "
              f"| {np.mean(pub_a):.3f} | {np.mean(dists):.2f} (median {np.median(dists):.2f}) |")

    print("\nMean centre distance (px) between our boxes and the authors' for the same tracker:\n")
    print("| sequence | " + " | ".join(configs) + " |")
    print("| --- |" + " --- |" * len(configs))
    for s, row in per_seq.items():
        print(f"| {s} | " + " | ".join(f"{row[c]:.2f}" for c in configs) + " |")

    print("\nPer-sequence precision@20 / AUC (ours, then the authors' run of the same tracker):\n")
    print("| sequence | " + " | ".join(configs) + " |")
    print("| --- |" + " --- |" * len(configs))
    for ds, names in sequences.items():
        for s in names:
            gt = read_results(pub_root / DATASETS[ds] / "groundtruth" / f"{s}.txt")
            cells = []
            for c in configs:
                a = score_sequence(read_results(args.out / c / DATASETS[ds] / f"{s}.txt"), gt)
                b = score_sequence(
                    read_results(pub_root / DATASETS[ds] / CONFIGS[c][2] / f"{s}.txt"), gt)
                cells.append(f"{a.precision20:.2f}/{a.auc:.2f} ({b.precision20:.2f}/{b.auc:.2f})")
            print(f"| {s} | " + " | ".join(cells) + " |")

    mapdiff = [c for c in configs if CONFIGS[c][2] in ("ARCF-H", "BACF")]
    if "uav123_10fps" in sequences and mapdiff:
        print("\nMean response-map difference, release form (largest singular value), frames 2..n, "
              "next to the published `map_diff` files (UAV123@10fps):\n")
        print("| sequence | " + " | ".join(f"{c} (authors')" for c in mapdiff) + " |")
        print("| --- |" + " --- |" * len(mapdiff))
        for s in sequences["uav123_10fps"]:
            cells = []
            for c in mapdiff:
                ours = np.loadtxt(args.out / c / "UAV123_10fps" / f"{s}_map_diff.txt",
                                  delimiter=",")[1:, 1]
                theirs = np.loadtxt(pub_root / "UAV123_10fps" / CONFIGS[c][2] /
                                    f"{s}_map_diff.txt")[1:]
                cells.append(f"{ours.mean():.4f} ({theirs.mean():.4f})")
            print(f"| {s} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

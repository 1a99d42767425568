"""The comparison table: every preset and OpenCV's CSRT, accuracy, speed and honesty, one run.

Each (tracker, sequence) runs in its own fresh process, single-threaded (BLAS, FFT and OpenCV
pinned to one thread), on frames decoded before timing; all trackers of one sequence run back
to back. On the 9 shared sequences: P@20 and AUC (toolkit convention) and the frame rate over
all their frames (frames / init + update seconds). On the 3 real full-occlusion clips
(``data/occlusions``) and the 9: the track-state goals of docs/track-state.md: real losses
flagged within 3 frames, found again within 10 frames of the target's return, hidden frames
claimed ``tracking`` after the flag, frames not ``tracking`` per 1,000 frames with IoU > 0.5.
CSRT reports no state (always ``tracking``) and runs from a separate virtual environment with
``opencv-contrib-python-headless`` (``--setup-csrt`` creates ``.venv-csrt``; see speed.py).

    python benchmarks/compare.py --setup-csrt        # about 4 minutes on 2 cores
    python benchmarks/compare.py --trackers arcf-nano,nanotrack
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from speed import PIN, ROOT, _read, add_csrt_arguments, csrt_python  # beside this script

TRACKERS = ("arcf-hc", "arcf-h", "bacf", "nanotrack", "vittrack", "arcf-nano", "csrt")
DATASETS = ("uav123_10fps", "dtb70", "uavdt")
CLIPS = ("car14", "person12_2", "group2_1")
STATE_CODES = {"tracking": 0, "coasting": 1, "lost": 2}


# ----------------------------------------------------------------------------- worker side
def worker(job_file: str, tracker_name: str) -> None:
    """In a fresh process: decode every frame, then time init + update; print one JSON line
    with the boxes (1-based), the states and the seconds per frame."""
    import cv2

    cv2.setNumThreads(1)
    job = json.loads(Path(job_file).read_text())
    frames = [_read(p) for p in job["frames"]]
    x, y, w, h = job["box"]
    boxes, states, seconds = [[x, y, w, h]], [0], []
    if tracker_name == "csrt":  # opencv-contrib only; OpenCV's rectangles are 0-based
        tracker = cv2.TrackerCSRT.create()  # type: ignore[attr-defined]
        t0 = time.perf_counter()
        tracker.init(frames[0], (round(x - 1), round(y - 1), round(w), round(h)))
        seconds.append(time.perf_counter() - t0)
        for f in frames[1:]:
            t0 = time.perf_counter()
            _, b = tracker.update(f)
            seconds.append(time.perf_counter() - t0)
            boxes.append([b[0] + 1, b[1] + 1, b[2], b[3]])
            states.append(0)
    else:
        import arcf

        arcf.warm_up()
        tracker = arcf.create_tracker(tracker_name)
        for i, f in enumerate(frames):
            t0 = time.perf_counter()
            r = tracker.init(f, (x, y, w, h)) if i == 0 else tracker.update(f)
            seconds.append(time.perf_counter() - t0)
            if i:
                boxes.append(list(r.box))
                states.append(STATE_CODES[r.state.value])
    print(json.dumps({"boxes": boxes, "states": states, "seconds": seconds}))


# ----------------------------------------------------------------------------- orchestrator
def _sequences(data: Path) -> list[tuple[str, Any, bool]]:
    from arcf.eval import load_dataset
    from arcf.eval.datasets import load_sequence

    out: list[tuple[str, Any, bool]] = []
    for ds in DATASETS:
        out += [(s.name, s, False) for s in load_dataset(ds, root=data / ds)]
    for clip in CLIPS:
        folder = data / "occlusions" / clip
        out.append((clip, load_sequence(folder / "img", folder / "groundtruth.txt", clip), True))
    return out


def _run(py: str, job: Path, tracker: str) -> dict[str, Any]:
    env = {**os.environ, **PIN}
    out = subprocess.run([py, str(Path(__file__).resolve()), "--worker", str(job), tracker],
                         env=env, capture_output=True, text=True, cwd=ROOT)
    if out.returncode != 0:
        print(out.stderr, file=sys.stderr)
        raise SystemExit(f"worker {tracker} on {job.stem} failed")
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def table(runs: dict[tuple[str, str], dict[str, Any]], seqs: list[tuple[str, Any, bool]],
          trackers: list[str]) -> list[str]:
    """The Markdown rows, one per tracker."""
    import numpy as np
    from track_state import Run, false_alarms, occlusion_episodes  # beside this script

    from arcf.eval import aggregate, score_sequence
    from arcf.eval.presence import pool as pool_presence
    from arcf.eval.presence import score_presence

    made: dict[str, list[Run]] = {}
    for t in trackers:
        made[t] = []
        for name, seq, clip in seqs:
            r = runs[(t, name)]
            n = len(r["boxes"])
            made[t].append(Run(
                preset=t, sequence=name, clip=clip, loss="", boxes=np.array(r["boxes"], float),
                groundtruth=np.array(seq.groundtruth, float), state=np.array(r["states"]),
                confidence=np.zeros(n), features=np.zeros((n, 1)),
                reacquired=np.zeros(n, bool), seconds=np.array(r["seconds"]),
                signals=np.full((n, 3), np.nan)))
    fps = {t: sum(len(r.seconds) for r in made[t] if not r.clip)
           / sum(float(r.seconds.sum()) for r in made[t] if not r.clip) for t in trackers}
    rows = ["| tracker | 9 sequences: P@20 / AUC | FPS (all frames) | × CSRT | 3 clips: "
            "P@20 / AUC | real losses flagged (≤ 3 frames) | found again (≤ 10 frames) | "
            "hidden frames claimed tracking | not tracking per 1,000 good frames | presence "
            "F, 12 runs |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for t in trackers:
        nine = aggregate({r.sequence: score_sequence(r.boxes, r.groundtruth)
                          for r in made[t] if not r.clip})
        clips = aggregate({r.sequence: score_sequence(r.boxes, r.groundtruth)
                           for r in made[t] if r.clip})
        eps = [e for r in made[t] for e in occlusion_episodes(r)]
        fa, good = false_alarms(made[t])
        presence = pool_presence(score_presence(r.boxes, r.groundtruth, r.state == 0)
                                 for r in made[t]).f_score
        ratio = f"{fps[t] / fps['csrt']:.1f}" if "csrt" in fps else "–"
        state = t != "csrt"
        rows.append(
            f"| `{t}` | {nine.precision20:.3f} / {nine.auc:.3f} | {fps[t]:.0f} | {ratio} | "
            f"{clips.precision20:.3f} / {clips.auc:.3f} | "
            + (f"{sum(e.flagged for e in eps)}/{len(eps)} | {sum(e.found for e in eps)}/"
               f"{len(eps)} | {sum(e.false_claims for e in eps)} | "
               f"{1000 * fa / max(good, 1):.1f} | {presence:.3f} |" if state
               else "no state | – | – | – | – |"))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", nargs=2, metavar=("JOB", "TRACKER"), help=argparse.SUPPRESS)
    ap.add_argument("--trackers", default=",".join(TRACKERS))
    add_csrt_arguments(ap)
    ap.add_argument("--data", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.worker:
        worker(*args.worker)
        return 0
    sys.path.insert(0, str(ROOT))
    from arcf.data import data_root
    from arcf.eval.environment import describe

    trackers = [t for t in args.trackers.split(",") if t]
    csrt = csrt_python(ap, args) if "csrt" in trackers else ""
    seqs = _sequences(args.data or data_root())
    runs: dict[tuple[str, str], dict[str, Any]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, seq, _ in seqs:
            job = Path(tmp) / f"{name}.json"
            job.write_text(json.dumps({"frames": [str(p) for p in seq.frames],
                                       "box": list(seq.init_box)}))
            for t in trackers:
                py = csrt if t == "csrt" else sys.executable
                runs[(t, name)] = r = _run(py, job, t)
                print(f"# {name} {t}: {len(r['seconds']) / sum(r['seconds']):.0f} FPS",
                      file=sys.stderr)
    print(f"`python benchmarks/compare.py {' '.join(argv or sys.argv[1:])}`".replace(" `", "`"))
    print(f"{time.strftime('%Y-%m-%d')}, {describe()}; one thread per tracker\n")
    print("\n".join(table(runs, seqs, trackers)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

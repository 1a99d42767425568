"""Speed benchmark: every preset (ARCF-HC, ARCF-H, BACF, the Siamese NanoTrack and VitTrack, the
hybrid arcf-nano) next to OpenCV's C++ CSRT on the same frames.

Frames are decoded before timing: the figure is tracker init + update only, as the paper and the
release measure it (FPS = frames / seconds). Each (tracker, sequence, thread mode) runs in its own
fresh process, so thread pinning applies before NumPy/SciPy/OpenCV load. CSRT comes from
``opencv-contrib-python-headless``, which must not replace the project's
``opencv-python-headless``: it runs from a separate virtual environment (``--csrt-python``;
``--setup-csrt`` creates ``.venv-csrt`` with pip).

    python benchmarks/speed.py --setup-csrt     # all local sequences, 1 and default threads
    python benchmarks/speed.py --threads 1 --sequences boat1,Animal3
    python benchmarks/speed.py --profile arcf-h --sequences boat1   # cProfile, top 20
    python benchmarks/speed.py --stages          # per-stage table next to each stage's floor
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

ROOT = Path(__file__).resolve().parent.parent
TRACKERS = ("csrt", "arcf-hc", "arcf-h", "bacf", "nanotrack", "vittrack", "arcf-nano")
PIN = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
       "NUMEXPR_NUM_THREADS": "1"}


# ----------------------------------------------------------------------------- worker side
def _read(path: str) -> np.ndarray:
    import cv2

    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise OSError(f"cannot decode {path}")
    return image


def worker(job_file: str, tracker_name: str, threads: str, profile: bool,
           stages: bool = False) -> None:
    """Runs in a fresh process: decode all frames, then time init + update."""
    import cv2
    import numpy as np

    cv2.setNumThreads(1 if threads == "1" else -1)
    job = json.loads(Path(job_file).read_text())
    frames = [_read(p) for p in job["frames"]]
    x, y, w, h = job["box"]
    kernels = 0.0  # loading (or compiling) arcf's Numba kernels, before any timing
    timer = None  # per-stage timers (``--stages``), arcf trackers only
    if tracker_name == "csrt":
        tracker = cv2.TrackerCSRT.create()  # type: ignore[attr-defined]  # opencv-contrib
        box0 = (round(x - 1), round(y - 1), round(w), round(h))  # OpenCV: 0-based integer rect
        t0 = time.perf_counter()
        tracker.init(frames[0], box0)
        first = time.perf_counter() - t0
        for f in frames[1:]:
            tracker.update(f)
        seconds = time.perf_counter() - t0
    else:
        import arcf

        kernels = arcf.warm_up()
        if stages:
            import stages as stage_timing

            timer = stage_timing.instrument()
        tracker = arcf.create_tracker(tracker_name)
        first = 0.0

        def run() -> float:
            nonlocal first
            t0 = time.perf_counter()
            steps = arcf.track_frames(tracker, frames, (x, y, w, h))
            first = next(steps).seconds
            for _ in steps:
                pass
            return time.perf_counter() - t0

        if profile:
            import cProfile
            import pstats

            prof = cProfile.Profile()
            seconds = prof.runcall(run)
            stats = pstats.Stats(prof, stream=sys.stderr)
            stats.sort_stats("tottime").print_stats(20)
        else:
            seconds = run()
    record = {"frames": len(frames), "seconds": seconds, "first_s": first,
              "kernels_s": kernels, "fps": len(frames) / seconds,
              "pixels": list(np.shape(frames[0]))}
    if timer is not None:
        timer.restore()
        record["stages"] = stage_timing.report(timer, seconds)
    print(json.dumps(record))


# ----------------------------------------------------------------------------- orchestrator
def setup_csrt(venv: Path) -> Path:
    py = venv / "bin" / "python"
    if not py.exists():
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        # the OpenCV range the project is tested with (pyproject.toml)
        subprocess.run([str(py), "-m", "pip", "install", "-q", "numpy",
                        "opencv-contrib-python-headless>=5.1,<5.2"], check=True)
    return py


def add_csrt_arguments(ap: argparse.ArgumentParser) -> None:
    """The options that name (or create) the interpreter CSRT runs in."""
    ap.add_argument("--csrt-python", type=Path, default=ROOT / ".venv-csrt" / "bin" / "python")
    ap.add_argument("--setup-csrt", action="store_true",
                    help="create .venv-csrt with opencv-contrib-python-headless if missing")


def csrt_python(ap: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """The interpreter for CSRT (opencv-contrib), created if asked; a usage error if absent."""
    path: Path = setup_csrt(ROOT / ".venv-csrt") if args.setup_csrt else args.csrt_python
    if not path.exists():
        ap.error(f"no CSRT interpreter at {path}; pass --setup-csrt or "
                 "--csrt-python PATH (a venv with opencv-contrib-python-headless)")
    return str(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", nargs=3, metavar=("JOB", "TRACKER", "THREADS"),
                    help=argparse.SUPPRESS)
    ap.add_argument("--profile", metavar="TRACKER", help="cProfile one tracker, print top 20")
    ap.add_argument("--stages", action="store_true",
                    help="arcf trackers only, single-threaded: time per stage next to its floor")
    ap.add_argument("--threads", default="1,default", help="'1', 'default' or both")
    ap.add_argument("--sequences", default="", help="comma-separated names (default: all local)")
    ap.add_argument("--trackers", default=",".join(TRACKERS))
    add_csrt_arguments(ap)
    ap.add_argument("--data", type=Path, default=None)
    args = ap.parse_args()
    if args.worker:
        job_file, tracker_name, threads = args.worker
        worker(job_file, tracker_name, threads, profile=bool(os.environ.get("ARCF_PROFILE")),
               stages=bool(os.environ.get("ARCF_STAGES")))
        return 0

    from arcf.data import data_root
    from arcf.eval import load_dataset

    data = args.data or data_root()
    wanted = [s for s in args.sequences.split(",") if s]
    seqs = []
    for ds in ("uav123_10fps", "dtb70", "uavdt"):
        try:
            seqs += [s for s in load_dataset(ds, root=data / ds) if not wanted or s.name in wanted]
        except Exception as exc:
            print(f"# skipping {ds}: {exc}", file=sys.stderr)
    trackers = [t for t in args.trackers.split(",") if t]
    if args.profile:
        trackers, modes = [args.profile], ["1"]
    elif args.stages:
        trackers, modes = [t for t in trackers if t != "csrt"], ["1"]
    else:
        modes = [m for m in args.threads.split(",") if m]
    csrt = csrt_python(ap, args) if "csrt" in trackers else ""

    fps: dict[tuple[str, str, str], float] = {}
    stage_runs: dict[str, list[tuple[int, dict]]] = {t: [] for t in trackers}
    first: dict[str, list[float]] = {t: [] for t in trackers}  # init (first frame) seconds
    kernels: list[float] = []  # arcf's kernel load per fresh process, seconds
    with tempfile.TemporaryDirectory() as tmp:
        for seq in seqs:
            job = Path(tmp) / f"{seq.name}.json"
            job.write_text(json.dumps({"frames": [str(p) for p in seq.frames],
                                       "box": list(seq.init_box)}))
            for mode in modes:
                for t in trackers:  # interleaved: all trackers of one sequence back to back
                    env = dict(os.environ)
                    if mode == "1":
                        env.update(PIN)
                    else:
                        for k in PIN:
                            env.pop(k, None)
                    if args.profile:
                        env["ARCF_PROFILE"] = "1"
                    if args.stages:
                        env["ARCF_STAGES"] = "1"
                    py = csrt if t == "csrt" else sys.executable
                    out = subprocess.run(
                        [py, str(Path(__file__).resolve()), "--worker", str(job), t, mode],
                        env=env, capture_output=True, text=True, cwd=ROOT,
                    )
                    if out.returncode != 0:
                        print(out.stderr, file=sys.stderr)
                        raise SystemExit(f"worker {t} on {seq.name} failed")
                    if args.profile:
                        print(out.stderr)
                    r = json.loads(out.stdout.strip().splitlines()[-1])
                    fps[(seq.name, mode, t)] = r["fps"]
                    if "stages" in r:
                        stage_runs[t].append((r["frames"], r["stages"]))
                    first[t].append(r["first_s"])
                    if t != "csrt":
                        kernels.append(r["kernels_s"])
                    print(f"# {seq.name} [{mode}] {t}: {r['fps']:.1f} FPS", file=sys.stderr)

    if args.profile:
        return 0
    if args.stages:
        print_stages(stage_runs)
        return 0
    from arcf.eval.environment import describe  # here: the CSRT workers' environment lacks it

    contrib = ""
    if csrt:  # CSRT runs on the OpenCV of its own environment
        cv = subprocess.run([csrt, "-c", "import cv2; print(cv2.__version__)"],
                            capture_output=True, text=True).stdout.strip()
        contrib = f"; CSRT: opencv-contrib {cv or '?'}"
    print(f"Machine: {describe()}{contrib}. FPS = frames / (init + update seconds), frames decoded "
          "beforehand; arcf's Numba kernels are loaded before timing (the service does so when "
          "a worker starts).\n")
    if kernels:
        print(f"Kernel load per fresh process (Numba cache present): median "
              f"{statistics.median(kernels) * 1e3:.0f} ms, max {max(kernels) * 1e3:.0f} ms.\n")
    print("First-frame latency (init), median / max over sequences: " + "; ".join(
        f"{t} {statistics.median(v) * 1e3:.1f} / {max(v) * 1e3:.1f} ms"
        for t, v in first.items() if v) + ".\n")
    for mode in modes:
        label = "single-threaded (BLAS/FFT/OpenCV pinned to 1 thread)" if mode == "1" else \
            "default threads"
        print(f"### {label}\n")
        print("| sequence | frames | " + " | ".join(trackers) + " | "
              + " | ".join(f"{t} / CSRT" for t in trackers if t != "csrt") + " |")
        print("| --- | --- |" + " --- |" * (2 * len(trackers) - 1))
        for seq in seqs:
            row = [f"{fps[(seq.name, mode, t)]:.1f}" for t in trackers]
            ratios = [f"{fps[(seq.name, mode, t)] / fps[(seq.name, mode, 'csrt')]:.2f}x"
                      for t in trackers if t != "csrt" and "csrt" in trackers]
            print(f"| {seq.name} | {len(seq)} | " + " | ".join(row + ratios) + " |")
        means = {t: sum(fps[(s.name, mode, t)] for s in seqs) / len(seqs) for t in trackers}
        ratio = {t: sum(fps[(s.name, mode, t)] / fps[(s.name, mode, "csrt")] for s in seqs)
                 / len(seqs) for t in trackers if t != "csrt" and "csrt" in trackers}
        print("| **mean** | | " + " | ".join(f"**{means[t]:.1f}**" for t in trackers) + " | "
              + " | ".join(f"**{ratio[t]:.2f}x**" for t in ratio) + " |")
        if "csrt" in trackers:
            med = {t: statistics.median(fps[(s.name, mode, t)] / fps[(s.name, mode, "csrt")]
                                        for s in seqs) for t in ratio}
            # aggregate: all frames over all seconds, i.e. FPS weighted by sequence length
            agg = {t: sum(len(s) for s in seqs) / sum(len(s) / fps[(s.name, mode, t)] for s in seqs)
                   for t in trackers}
            print("| median ratio | | " + " |" * len(trackers) + " "
                  + " | ".join(f"{med[t]:.2f}x" for t in med) + " |")
            print("| all frames / all seconds | | "
                  + " | ".join(f"{agg[t]:.1f}" for t in trackers) + " | "
                  + " | ".join(f"{agg[t] / agg['csrt']:.2f}x" for t in ratio) + " |")
        print()
    return 0


def print_stages(stage_runs: dict[str, list[tuple[int, dict]]]) -> None:
    """Per-tracker table: ms per frame of each stage over all frames, share, floor."""
    from stages import STAGES

    from arcf.eval.environment import describe

    print(f"Machine: {describe()}; single-threaded; stage "
          "times are exclusive (a stage called inside another is charged to itself); floors "
          "as defined in benchmarks/stages.py.\n")
    for t, runs in stage_runs.items():
        if not runs:
            continue
        frames = sum(n for n, _ in runs)
        sec = {s: sum(r["seconds"][s] for _, r in runs) for s in STAGES}
        floors = {s: sum(r["floors"][s] for _, r in runs) for s in runs[0][1]["floors"]}
        bandwidth = statistics.median(r["bandwidth"] for _, r in runs)
        total = sum(sec.values())
        print(f"### {t}: {1e3 * total / frames:.2f} ms per frame over {frames} frames of "
              f"{len(runs)} sequences (copy bandwidth {bandwidth / 1e9:.1f} GB/s)\n")
        print("| stage | ms per frame | share | floor, ms per frame | time / floor |")
        print("| --- | --- | --- | --- | --- |")
        for s in STAGES:
            floor = floors.get(s)
            ms = 1e3 * sec[s] / frames
            cells = (f"{1e3 * floor / frames:.2f} | {sec[s] / floor:.1f}x"
                     if floor else "— | —")
            print(f"| {s} | {ms:.2f} | {100 * sec[s] / total:.0f} % | {cells} |")
        print()


if __name__ == "__main__":
    raise SystemExit(main())

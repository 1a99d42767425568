"""Does the tracker say the truth about itself? The track-state goals, measured.

Every preset, as shipped (or with ``--set`` overrides), runs the 9 shared sequences and the 3
real full-occlusion clips of ``data/occlusions``. Per frame: its box against the ground truth,
its state and confidence. Printed as Markdown (docs/track-state.md):

1. **Real losses flagged**: per occlusion episode (a run of 3 or more frames without a visible
   target), does the state leave ``tracking`` by the 3rd frame after the first hidden frame?
2. **Found again**: within 10 frames after the target is visible again, a frame ``tracking``
   with IoU > 0.5; and no frame claims ``tracking`` while the target is hidden, once flagged.
3. **No crying wolf**: frames not ``tracking`` per 1,000 frames whose box has IoU > 0.5.
4. **Nothing lost elsewhere**: P@20 / AUC (toolkit convention) on the 9 shared sequences, next
   to the same preset with ``state.reacquire`` off (the paper's tracker: its boxes).
6. **Confidence**: a reliability table (confidence bins against the fraction of frames whose box
   overlaps the target) and the expected calibration error; ``--fit`` also fits the confidence
   model (``StateParams.weights``/``bias``) on these runs, per preset, and prints its
   leave-one-sequence-out calibration error.

    python benchmarks/track_state.py                     # ~3 min on 2 cores
    python benchmarks/track_state.py --presets arcf-h --set state.resume_above=0.5
    python benchmarks/track_state.py --fit
    python benchmarks/track_state.py --simulated 12   # also the 9 sequences with their
                                                      # target covered for 12 frames
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from scipy.optimize import minimize

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from arcf.cli import parse_override
from arcf.data import data_root
from arcf.eval.failure import episodes
from arcf.eval.metrics import overlaps, score_sequence
from arcf.state import FEATURES

PRESETS = ("arcf-hc", "arcf-h", "bacf")
DATASETS = ("uav123_10fps", "dtb70", "uavdt")
CLIPS = ("car14", "person12_2", "group2_1")
#: goal 1: frames after the first hidden one by which the state must have left tracking
FLAG_WITHIN = 3
#: goal 2: frames after the target is visible again within which it must be tracked again
FOUND_WITHIN = 10
#: an occlusion episode: at least this many frames in a row without a visible target
MIN_EPISODE = 3
STATE_CODES = {"tracking": 0, "coasting": 1, "lost": 2}


@dataclass
class Run:
    """One sequence tracked by one preset. Arrays have one row per frame (frame 0: the box
    given)."""

    preset: str
    sequence: str
    clip: bool
    boxes: np.ndarray  #: (N, 4)
    groundtruth: np.ndarray  #: (N, 4), NaN rows where no target is visible
    state: np.ndarray  #: (N,) STATE_CODES
    confidence: np.ndarray  #: (N,)
    features: np.ndarray  #: (N, len(FEATURES)) the confidence model's features (NaN on frame 0)
    reacquired: np.ndarray  #: (N,) bool
    seconds: np.ndarray  #: (N,) tracker time

    @property
    def hidden(self) -> np.ndarray:
        return ~np.all(np.isfinite(self.groundtruth), axis=1)

    @property
    def iou(self) -> np.ndarray:
        gt = np.where(self.hidden[:, None], 1.0, self.groundtruth)
        iou = np.nan_to_num(overlaps(self.boxes, gt), nan=0.0)
        iou[self.hidden] = 0.0
        return iou


def _sequence(kind: str, name: str) -> Any:
    from arcf.eval import load_dataset
    from arcf.eval.datasets import load_sequence

    if kind == "clip":
        folder = data_root() / "occlusions" / name
        return load_sequence(folder / "img", folder / "groundtruth.txt", name)
    (seq,) = load_dataset(kind, sequences=[name])
    return seq


def run(preset: str, kind: str, name: str, overrides: dict[str, Any],
        simulated: int = 0) -> Run:
    """One preset on one sequence; with ``simulated``, its target covered for that many frames
    from the middle (their ground truth then says: not visible)."""

    import arcf

    seq = _sequence(kind, name)
    groundtruth = np.array(seq.groundtruth, dtype=float)
    if simulated:
        from reacquire import occluded_frames  # benchmarks/reacquire.py, beside this script

        start = len(seq.frames) // 2
        frames = occluded_frames(seq.frames, groundtruth.copy(), start, simulated)
        groundtruth[start:start + simulated] = np.nan
    else:
        frames = (seq.read_frame(i) for i in range(len(seq.frames)))
    tracker: Any = arcf.create_tracker(preset, **overrides)
    features: list[tuple[float, ...]] = [(np.nan,) * len(FEATURES)]
    # the ARCF filter whose confidence model reads the features (the hybrid's verifier); a
    # Siamese tracker's confidence is its network's score: no features
    monitored = getattr(tracker, "verifier", tracker)
    monitor = getattr(monitored, "_monitor", None)
    if monitor is not None and isinstance(monitored, arcf.ARCFTracker):
        confidence = monitor.confidence

        def recording(*args: Any) -> Any:  # the features each frame's confidence was read from
            c, f = confidence(*args)
            features.append(f)
            return c, f

        monitor.confidence = recording
    boxes, state, conf, reacq, secs = [], [], [], [], []
    for i, frame in enumerate(frames):
        t0 = time.perf_counter()
        r = tracker.init(frame, seq.init_box) if i == 0 else tracker.update(frame)
        secs.append(time.perf_counter() - t0)
        boxes.append(r.box)
        state.append(STATE_CODES[r.state.value])
        conf.append(r.confidence)
        reacq.append(r.reacquired)
        if len(features) < len(boxes):  # no confidence model read this frame
            features.append((np.nan,) * len(FEATURES))
    return Run(preset, name + (f"+{simulated}" if simulated else ""), kind == "clip",
               np.array(boxes, float), groundtruth,
               np.array(state), np.array(conf), np.array(features, float), np.array(reacq),
               np.array(secs))


def all_runs(presets: list[str], overrides: dict[str, Any], jobs: int,
             simulated: int = 0) -> list[Run]:
    """Every preset on the shared sequences and the clips (``simulated``: the shared
    sequences only, each with its target covered)."""
    from arcf.eval import load_dataset

    todo = [(p, ds, s.name) for p in presets for ds in DATASETS
            if (data_root() / ds).is_dir() for s in load_dataset(ds)]
    if not simulated:
        todo += [(p, "clip", c) for p in presets for c in CLIPS
                 if (data_root() / "occlusions" / c).is_dir()]
    with ProcessPoolExecutor(jobs) as pool:
        return list(pool.map(run, *zip(*todo, strict=True), [overrides] * len(todo),
                             [simulated] * len(todo)))


# ------------------------------------------------------------------------------ the goals
@dataclass
class Episode:
    sequence: str
    start: int
    stop: int  #: exclusive: the first frame with the target visible again (or the end)
    flagged: bool
    found: bool
    #: frames claimed ``tracking`` while the target was hidden, after the first flag
    false_claims: int


def occlusion_episodes(r: Run) -> list[Episode]:
    out = []
    for start, stop in episodes(r.hidden):
        if stop - start < MIN_EPISODE:
            continue
        flagged = bool((r.state[start:start + FLAG_WITHIN + 1] != 0).any())
        flags = np.flatnonzero(r.state[start:stop] != 0)
        claims = int((r.state[start + flags[0]:stop] == 0).sum()) if flags.size else 0
        after = slice(stop, min(stop + FOUND_WITHIN, len(r.state)))
        found = bool(((r.state[after] == 0) & (r.iou[after] > 0.5)).any())
        out.append(Episode(r.sequence, start, stop, flagged, found, claims))
    return out


def false_alarms(runs: list[Run]) -> tuple[int, int]:
    """(frames not tracking among those with IoU > 0.5, frames with IoU > 0.5), frame 0 out."""
    good = [r.iou[1:] > 0.5 for r in runs]
    return (sum(int((r.state[1:][g] != 0).sum()) for r, g in zip(runs, good, strict=True)),
            sum(int(g.sum()) for g in good))


def reliability(conf: np.ndarray, hit: np.ndarray, bins: int = 10) -> tuple[list[str], float]:
    """Markdown rows of the reliability table and the expected calibration error (bins of
    equal width; the error weighs each bin by its share of frames)."""
    rows, ece = [], 0.0
    edges = np.linspace(0, 1, bins + 1)
    for k in range(bins):
        lo, hi = edges[k], edges[k + 1]
        m = (conf >= lo) & ((conf < hi) if k < bins - 1 else (conf <= hi))
        if not m.any():
            rows.append(f"| {lo:.1f}–{hi:.1f} | 0 | – | – |")
            continue
        ece += m.mean() * abs(conf[m].mean() - hit[m].mean())
        rows.append(f"| {lo:.1f}–{hi:.1f} | {int(m.sum())} | {conf[m].mean():.3f} | "
                    f"{hit[m].mean():.3f} |")
    return rows, float(ece)


def _confidences(runs: list[Run]) -> tuple[np.ndarray, np.ndarray]:
    conf = np.concatenate([r.confidence[1:] for r in runs])
    hit = np.concatenate([r.iou[1:] > 0 for r in runs])
    return conf, hit


# ------------------------------------------------------------------------------ fitting
def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1e-3) -> tuple[np.ndarray, float]:
    """Weights and bias of the maximum-likelihood logistic model (a small L2 penalty on the
    weights), every frame weighing the same: a calibrated probability, not a balanced
    classifier."""
    xb = np.hstack([x, np.ones((len(x), 1))])

    def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
        z = xb @ theta
        ll = np.where(y == 1, np.logaddexp(0, -z), np.logaddexp(0, z))
        p = 1.0 / (1.0 + np.exp(-z))
        reg = np.r_[theta[:-1], 0.0]
        return float(ll.mean() + 0.5 * l2 * reg @ reg), xb.T @ (p - y) / len(y) + l2 * reg

    theta = minimize(loss, np.zeros(xb.shape[1]), jac=True, method="L-BFGS-B").x
    return theta[:-1], float(theta[-1])


def fit(runs: list[Run]) -> list[str]:
    """The confidence model, one for every preset, fitted on all the runs; and its
    calibration error when every sequence is scored by a model fitted without it (under any
    preset): what to expect on sequences it never saw."""
    xs = [r.features[1:] for r in runs]
    ys = [(r.iou[1:] > 0).astype(float) for r in runs]
    ok = [np.all(np.isfinite(x), axis=1) for x in xs]

    def fitted(idx: list[int]) -> tuple[np.ndarray, float]:
        return fit_logistic(np.vstack([xs[j][ok[j]] for j in idx]),
                            np.concatenate([ys[j][ok[j]] for j in idx]))

    w, b = fitted(list(range(len(runs))))
    conf: list[np.ndarray] = [np.empty(0)] * len(runs)
    for name in sorted({r.sequence for r in runs}):
        held = [j for j, r in enumerate(runs) if r.sequence == name]
        wj, bj = fitted([j for j, r in enumerate(runs) if r.sequence != name])
        for j in held:
            conf[j] = 1.0 / (1.0 + np.exp(-(xs[j][ok[j]] @ wj + bj)))
    lines = [f"weights=({', '.join(f'{v:.4f}' for v in w)}),  # {', '.join(FEATURES)}",
             f"bias={b:.4f}", "", "Leave-one-sequence-out expected calibration error:"]
    for preset in [*sorted({r.preset for r in runs}), None]:
        idx = [j for j, r in enumerate(runs) if preset in (None, r.preset)]
        _, ece = reliability(np.concatenate([conf[j] for j in idx]),
                             np.concatenate([ys[j][ok[j]] for j in idx]).astype(bool))
        lines.append(f"- {preset or 'pooled'}: {ece:.3f}")
    return lines


# ------------------------------------------------------------------------------ report
def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def report(runs: list[Run], plain: list[Run], args: argparse.Namespace) -> None:
    print(f"`python benchmarks/track_state.py {' '.join(sys.argv[1:])}`".replace(" `", "`"))
    print(f"{time.strftime('%Y-%m-%d')}, {_cpu()}, "
          f"nproc {os.cpu_count()}; overrides {args.set or 'none (the presets as shipped)'}\n")
    print("| preset | 1. losses flagged within 3 frames | 2. found again within 10 frames "
          "| hidden frames claimed tracking | 3. not tracking per 1,000 good frames | "
          "4. P@20 / AUC (reacquire off) | 6. ECE | ms / frame (median) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for preset in args.presets:
        mine = [r for r in runs if r.preset == preset]
        eps = [e for r in mine for e in occlusion_episodes(r)]
        fa, good = false_alarms(mine)
        nine = [r for r in mine if not r.clip]
        base = [r for r in plain if r.preset == preset and not r.clip]
        p, a = (np.mean([score_sequence(r.boxes, r.groundtruth).precision20 for r in nine]),
                np.mean([score_sequence(r.boxes, r.groundtruth).auc for r in nine]))
        plain_scores = "–"
        if base:
            pb = float(np.mean([score_sequence(r.boxes, r.groundtruth).precision20
                                for r in base]))
            ab = float(np.mean([score_sequence(r.boxes, r.groundtruth).auc for r in base]))
            plain_scores = f"{pb:.3f} / {ab:.3f}"
        _, ece = reliability(*_confidences(mine))
        ms = 1000 * np.median(np.concatenate([r.seconds[1:] for r in mine]))
        print(f"| `{preset}` | {sum(e.flagged for e in eps)}/{len(eps)} "
              f"({', '.join(e.sequence + ('' if e.flagged else ' ✗') for e in eps)}) | "
              f"{sum(e.found for e in eps)}/{len(eps)} "
              f"({', '.join(e.sequence + ('' if e.found else ' ✗') for e in eps)}) | "
              f"{sum(e.false_claims for e in eps)} | {1000 * fa / max(good, 1):.1f} "
              f"({fa}/{good}) | {p:.3f} / {a:.3f} ({plain_scores}) | {ece:.3f} | "
              f"{ms:.1f} |")
    print("\nReliability (all presets pooled; a frame counts as a hit when its box overlaps "
          "the target, IoU > 0):\n")
    rows, ece = reliability(*_confidences(runs))
    print("| confidence | frames | mean confidence | fraction with IoU > 0 |")
    print("| --- | ---: | ---: | ---: |")
    print("\n".join(rows))
    print(f"\nExpected calibration error, pooled: {ece:.3f}")
    if args.fit:
        print("\nConfidence model fitted on these runs (StateParams):\n")
        print("\n".join(fit(runs)))


def simulated_report(runs: list[Run], length: int) -> None:
    """Goals 1-3 on the shared sequences with their target covered (a second set of
    episodes, simulated: the target moves on under a patch of the frame's own texture)."""
    print(f"\nThe 9 shared sequences with the target covered for {length} frames from the "
          "middle (`benchmarks/reacquire.py`'s simulated occlusion):\n")
    print("| preset | losses flagged within 3 frames | found again within 10 frames | "
          "hidden frames claimed tracking | not tracking per 1,000 good frames |")
    print("| --- | --- | --- | --- | --- |")
    for preset in sorted({r.preset for r in runs}):
        mine = [r for r in runs if r.preset == preset]
        eps = [e for r in mine for e in occlusion_episodes(r)]
        fa, good = false_alarms(mine)
        print(f"| `{preset}` | {sum(e.flagged for e in eps)}/{len(eps)} | "
              f"{sum(e.found for e in eps)}/{len(eps)} | {sum(e.false_claims for e in eps)} | "
              f"{1000 * fa / max(good, 1):.1f} ({fa}/{good}) |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", type=lambda s: s.split(","), default=list(PRESETS))
    ap.add_argument("--set", action="append", type=parse_override, metavar="KEY=VALUE",
                    help="override a parameter of every preset, e.g. --set state.probes=3")
    ap.add_argument("--fit", action="store_true", help="fit the confidence model too")
    ap.add_argument("--simulated", type=int, default=0, metavar="N",
                    help="also cover the target of each shared sequence for N frames")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    overrides = dict(args.set or [])
    runs = all_runs(args.presets, overrides, args.jobs)
    # the paper's tracker beside each ARCF preset (the Siamese ones and the hybrid take no
    # overrides: they have no plain version)
    from arcf.presets import PRESETS as ARCF_PRESETS

    plain = all_runs([p for p in args.presets if p in ARCF_PRESETS],
                     {**overrides, "state.reacquire": False}, args.jobs)
    report(runs, plain, args)
    if args.simulated:
        simulated_report(all_runs(args.presets, overrides, args.jobs, args.simulated),
                         args.simulated)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

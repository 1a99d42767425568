"""Does the tracker say the truth about itself? The track-state goals, measured.

Every preset, as shipped (or with ``--set`` overrides), runs the 9 shared sequences and the 3
real full-occlusion clips of ``data/occlusions``; with ``--losses N``, also the 9 shared
sequences with a made loss of N frames of each kind of :mod:`arcf.eval.losses` (a cover, a cut
to another video, a pan out of view). Per frame: its box against the ground truth, its state
and confidence. Printed as Markdown (docs/track-state.md), one row per preset:

1. **Losses flagged**: per loss episode (a run of 3 or more frames without a visible target),
   does the state leave ``tracking`` by the 3rd frame after the first hidden frame? **Found
   again**: within 10 frames after the target is visible again, a frame ``tracking`` with
   IoU > 0.5 (and no frame claims ``tracking`` while the target is hidden, once flagged).
   **No crying wolf**: frames not ``tracking`` per 1,000 frames whose box has IoU > 0.5.
2. **Never worse than not searching**: P@20 / AUC (toolkit convention) next to the same runs
   with ``state.reacquire`` off (for ARCF-H and BACF, which ship with it off, the same).
3. **Presence** (:mod:`arcf.eval.presence`, a frame is reported present when ``tracking``):
   precision, recall and F-score, and VOT-LT's overlap-weighted tracking F-score.
6. **Confidence**: a reliability table and the expected calibration error; ``--fit`` fits
   the confidence model (``StateParams.weights``/``bias``) on ``--features`` of these runs,
   shared by ARCF's presets and per preset, and prints in-sample and leave-one-sequence-out
   calibration errors (a sequence and its made losses held out together).

Every header line names the machine and the versions (OpenCV's moves NanoTrack's boxes).

    python benchmarks/track_state.py                     # ~3 min on 2 cores
    python benchmarks/track_state.py --presets arcf-h --set state.resume_above=0.5
    python benchmarks/track_state.py --presets arcf-hc,arcf-h,bacf,arcf-nano,nanotrack,\
        vittrack --losses 12 --fit --features ln_psr,look,ln_frames --cache /tmp/ts  # ~5 min
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import pickle
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
from arcf.eval.environment import describe
from arcf.eval.failure import episodes
from arcf.eval.losses import KINDS, Loss, LossKind, make_loss
from arcf.eval.metrics import overlaps, score_sequence
from arcf.eval.presence import PresenceScore, score_presence
from arcf.eval.presence import pool as pool_presence
from arcf.state import FEATURES, StateParams, TrackMonitor

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
    #: the kind of made loss (:mod:`arcf.eval.losses`), "" for a sequence as it is
    loss: str
    boxes: np.ndarray  #: (N, 4)
    groundtruth: np.ndarray  #: (N, 4), NaN rows where no target is visible
    state: np.ndarray  #: (N,) STATE_CODES
    confidence: np.ndarray  #: (N,)
    features: np.ndarray  #: (N, len(FEATURES)) the confidence model's features (NaN on frame 0)
    reacquired: np.ndarray  #: (N,) bool
    seconds: np.ndarray  #: (N,) tracker time
    #: (N, 3) what the state machine read: peak, PSR, the release's aberrance
    signals: np.ndarray

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


def _shared() -> list[tuple[str, str]]:
    """(dataset, sequence) of every shared sequence here, in a fixed order."""
    from arcf.eval import load_dataset

    return [(ds, s.name) for ds in DATASETS if (data_root() / ds).is_dir()
            for s in load_dataset(ds)]


def _loss(kind: LossKind, dataset: str, name: str, length: int) -> Loss | None:
    """The shared sequence with a made loss of ``kind`` (:mod:`arcf.eval.losses`); a cut shows
    the next shared sequence's frames meanwhile."""
    shared = _shared()
    seq = _sequence(dataset, name)
    other = _sequence(*shared[(shared.index((dataset, name)) + 1) % len(shared)])
    return make_loss(kind, name, seq.frames, seq.groundtruth, length, other.frames)


def run(preset: str, kind: str, name: str, overrides: dict[str, Any],
        loss: str = "", length: int = 0) -> Run | None:
    """One preset on one sequence (``kind``: its dataset, or "clip"); with ``loss``, the
    sequence with a made loss of that kind and ``length`` (None when it cannot take one)."""

    import arcf

    if loss:
        made = _loss(loss, kind, name, length)  # type: ignore[arg-type]
        if made is None:
            return None
        groundtruth, frames, label = made.groundtruth, made.frames(), made.name
        init_box = tuple(float(v) for v in groundtruth[0])
    else:
        seq = _sequence(kind, name)
        groundtruth = np.array(seq.groundtruth, dtype=float)
        frames = (seq.read_frame(i) for i in range(len(seq.frames)))
        label, init_box = name, seq.init_box
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
    boxes, state, conf, reacq, secs, signals = [], [], [], [], [], []
    for i, frame in enumerate(frames):
        t0 = time.perf_counter()
        r = tracker.init(frame, init_box) if i == 0 else tracker.update(frame)
        secs.append(time.perf_counter() - t0)
        boxes.append(r.box)
        state.append(STATE_CODES[r.state.value])
        conf.append(r.confidence)
        reacq.append(r.reacquired)
        signals.append((r.peak, r.psr, r.aberrance_release))
        if len(features) < len(boxes):  # no confidence model read this frame
            features.append((np.nan,) * len(FEATURES))
    return Run(preset, label, kind == "clip", loss, np.array(boxes, float), groundtruth,
               np.array(state), np.array(conf), np.array(features, float), np.array(reacq),
               np.array(secs), np.array(signals, float))


def _cached(cache: Path | None, preset: str, kind: str, name: str,
            overrides: dict[str, Any], loss: str, length: int) -> Run | None:
    """:func:`run`, or its result from ``cache`` (a folder of ``.pkl`` files keyed by every
    argument and the code's commit: a changed tracker never reads an old run)."""
    if cache is None:
        return run(preset, kind, name, overrides, loss, length)
    key = hashlib.sha256(repr((preset, kind, name, sorted(overrides.items()), loss, length,
                               _revision())).encode()).hexdigest()[:20]
    path = cache / f"{preset}-{name}-{loss}{length}-{key}.pkl"
    if path.is_file():
        with path.open("rb") as f:
            fields = pickle.load(f)  # our own cache: the fields, whatever module ran it
        return None if fields is None else Run(**fields)
    out = run(preset, kind, name, overrides, loss, length)
    cache.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        pickle.dump(None if out is None else vars(out), f)
    return out


def _revision() -> str:
    """The commit and whether the tracker's code differs from it (a cache key)."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                              text=True, check=True).stdout.strip()
        diff = subprocess.run(["git", "diff", "HEAD", "--", "arcf"], cwd=root,
                              capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + hashlib.sha256(diff.encode()).hexdigest()[:12]


def all_runs(presets: list[str], overrides: dict[str, Any], jobs: int,
             losses: tuple[str, ...] = (), length: int = 0,
             cache: Path | None = None) -> list[Run]:
    """Every preset on the shared sequences and the clips; with ``losses``, on the shared
    sequences with each kind of made loss of ``length`` frames instead."""
    shared = _shared()
    if losses:
        todo = [(p, ds, s, lo) for p in presets for lo in losses for ds, s in shared]
    else:
        todo = [(p, ds, s, "") for p in presets for ds, s in shared]
        todo += [(p, "clip", c, "") for p in presets for c in CLIPS
                 if (data_root() / "occlusions" / c).is_dir()]
    with ProcessPoolExecutor(jobs) as pool:
        out = pool.map(_cached, [cache] * len(todo), *list(zip(*todo, strict=True))[:3],
                       [overrides] * len(todo), [t[3] for t in todo], [length] * len(todo))
        return [r for r in out if r is not None]


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


def _group(r: Run) -> str:
    """The source sequence of a run: its made-loss variants are held out with it."""
    return r.sequence.split("+", 1)[0]


def fit(runs: list[Run], features: tuple[str, ...] = FEATURES) -> list[str]:
    """The confidence model fitted on the runs, on ``features`` only (the others weigh 0): one
    model shared by ARCF's presets (what ``StateParams`` ships for them) and one per preset
    (the hybrid ships its own); and each one's calibration error per preset when every source
    sequence (with its made losses) is scored by a model fitted without it: what to expect on
    sequences it never saw."""
    use = [FEATURES.index(f) for f in features]
    xs = [r.features[1:, use] for r in runs]
    ys = [(r.iou[1:] > 0).astype(float) for r in runs]
    ok = [np.all(np.isfinite(x), axis=1) for x in xs]

    def fitted(idx: list[int]) -> tuple[np.ndarray, float]:
        return fit_logistic(np.vstack([xs[j][ok[j]] for j in idx]),
                            np.concatenate([ys[j][ok[j]] for j in idx]))

    def held_out(pool: list[int]) -> list[np.ndarray]:
        conf: list[np.ndarray] = [np.empty(0)] * len(runs)
        for name in sorted({_group(runs[j]) for j in pool}):
            wj, bj = fitted([j for j in pool if _group(runs[j]) != name])
            for j in pool:
                if _group(runs[j]) == name:
                    conf[j] = 1.0 / (1.0 + np.exp(-(xs[j][ok[j]] @ wj + bj)))
        return conf

    def in_sample(idx: list[int]) -> list[np.ndarray]:
        w, b = fitted(idx)
        conf: list[np.ndarray] = [np.empty(0)] * len(runs)
        for j in idx:
            conf[j] = 1.0 / (1.0 + np.exp(-(xs[j][ok[j]] @ w + b)))
        return conf

    def ece(conf: list[np.ndarray], idx: list[int]) -> float:
        return reliability(np.concatenate([conf[j] for j in idx]),
                           np.concatenate([ys[j][ok[j]] for j in idx]).astype(bool))[1]

    def brier(conf: list[np.ndarray], idx: list[int]) -> str:
        """The Brier score (a proper scoring rule: a constant cannot game it, as it can the
        calibration error) and the mean confidence on frames without a visible target."""
        c = np.concatenate([conf[j] for j in idx])
        y = np.concatenate([ys[j][ok[j]] for j in idx])
        hidden = np.concatenate([runs[j].hidden[1:][ok[j]] for j in idx])
        return f"{np.mean((c - y) ** 2):.3f}, {c[hidden].mean() if hidden.any() else np.nan:.2f}"

    def weights(idx: list[int]) -> str:
        w, b = fitted(idx)
        full = np.zeros(len(FEATURES))
        full[use] = w
        return f"weights=({', '.join(f'{v:.4f}' for v in full)}), bias={b:.4f}"

    from arcf.presets import PRESETS as ARCF_PRESETS

    usable = [j for j in range(len(runs)) if ok[j].any()]
    shared_idx = [j for j in usable if runs[j].preset in ARCF_PRESETS]
    presets = sorted({runs[j].preset for j in usable})
    lines = [f"Features: {', '.join(features)} (weights in the order {', '.join(FEATURES)})",
             ""]
    shared_in = in_sample(shared_idx) if shared_idx else []
    shared_out = held_out(shared_idx) if shared_idx else []
    if shared_idx:
        lines += [f"Shared by ARCF's presets: {weights(shared_idx)}", ""]
    rows = ["| preset | in-sample ECE, shared | in-sample ECE, own | leave-one-sequence-out "
            "ECE, shared | leave-one-sequence-out ECE, own | leave-one-sequence-out Brier, "
            "hidden frames' mean confidence: shared | the same, own |",
            "| --- | --- | --- | --- | --- | --- | --- |"]
    for preset in presets:
        idx = [j for j in usable if runs[j].preset == preset]
        lines.append(f"Own model of `{preset}`: {weights(idx)}")
        shared_cells = (f"{ece(shared_in, idx):.3f} | " if preset in ARCF_PRESETS else "– | ")
        shared_lo = (f"{ece(shared_out, idx):.3f} | " if preset in ARCF_PRESETS else "– | ")
        shared_brier = brier(shared_out, idx) if preset in ARCF_PRESETS else "–"
        own_out = held_out(idx)
        rows.append(f"| `{preset}` | {shared_cells}{ece(in_sample(idx), idx):.3f} | "
                    f"{shared_lo}{ece(own_out, idx):.3f} | {shared_brier} | "
                    f"{brier(own_out, idx)} |")
    return [*lines, "", *rows]


# ------------------------------------------------------------------------------ tuning
#: the state machine's thresholds ``--tune`` searches (the others as shipped)
TUNE_GRID: dict[str, tuple[float, ...]] = {
    "coast_below": (0.2, 0.25, 0.33, 0.4, 0.5), "resume_above": (0.4, 0.5, 0.6, 0.7, 0.8)}


def replay(r: Run, params: StateParams) -> np.ndarray:
    """The states the machine with ``params`` gives on the run's recorded signals: exactly the
    states a run with those thresholds would report where the state decides nothing else
    (re-acquisition off: every frame is learnt, nothing is searched)."""
    monitor = TrackMonitor(params)
    monitor.reset()
    out = [STATE_CODES["tracking"]]
    for peak, psr, aberrance in r.signals[1:]:
        out.append(STATE_CODES[monitor.observe(peak, psr, aberrance).state.value])
    return np.array(out)


def _with_states(r: Run, state: np.ndarray) -> Run:
    return dataclasses.replace(r, state=state)


def tune(runs: list[Run], preset: str) -> list[str]:
    """``coast_below`` and ``resume_above`` of a preset whose state decides nothing but itself
    (re-acquisition off), chosen for the presence F-score on its runs by replaying the machine
    on their recorded signals: in-sample (all runs) and leave-one-sequence-out (each source
    sequence, with its made losses, judged by thresholds chosen without it)."""
    from arcf.presets import PRESETS as ARCF_PRESETS

    base = ARCF_PRESETS[preset].state
    mine = [r for r in runs if r.preset == preset]
    if base.reacquire or not mine:
        return [f"`{preset}`: re-acquisition on, its state decides what is learnt: not "
                "replayable"]
    shipped = np.array([replay(r, base) for r in mine[:3]], dtype=object)
    if not all(np.array_equal(s, r.state) for s, r in zip(shipped, mine[:3], strict=True)):
        return [f"`{preset}`: the replay does not reproduce the run's states (overrides?)"]
    grid = [dataclasses.replace(base, coast_below=c, resume_above=u)
            for c in TUNE_GRID["coast_below"] for u in TUNE_GRID["resume_above"]
            if base.lost_below <= c <= u]
    states = {g: [replay(r, g) for r in mine] for g in grid}

    def f_score(g: StateParams, idx: list[int]) -> float:
        return pool_presence(score_presence(mine[j].boxes, mine[j].groundtruth,
                                            states[g][j] == 0) for j in idx).f_score

    every = list(range(len(mine)))
    best = max(grid, key=lambda g: f_score(g, every))
    held: list[Run] = []
    chosen = []
    for name in sorted({_group(r) for r in mine}):
        train = [j for j in every if _group(mine[j]) != name]
        g = max(grid, key=lambda g: f_score(g, train))
        chosen.append(f"{name}: {g.coast_below:g} / {g.resume_above:g}")
        held += [_with_states(mine[j], states[g][j]) for j in every if _group(mine[j]) == name]
    tuned = [_with_states(r, states[best][j]) for j, r in enumerate(mine)]
    return [f"`{preset}`, {len(mine)} runs, presence F-score of the replayed states; shipped "
            f"coast_below / resume_above {base.coast_below:g} / {base.resume_above:g}, best "
            f"in-sample {best.coast_below:g} / {best.resume_above:g}; chosen without each "
            f"sequence: {', '.join(chosen)}", "",
            f"| thresholds {GOAL_HEADER}", "| --- " * (GOAL_HEADER.count("|") + 1) + "|",
            goal_row("shipped", mine, []), goal_row("best in-sample", tuned, []),
            goal_row("leave-one-sequence-out", held, []), ""]


# ------------------------------------------------------------------------------ report
def _scores(runs: list[Run]) -> tuple[float, float]:
    """Mean P@20 and AUC over the runs (toolkit convention)."""
    scores = [score_sequence(r.boxes, r.groundtruth) for r in runs]
    return (float(np.mean([s.precision20 for s in scores])),
            float(np.mean([s.auc for s in scores])))


def _presence(runs: list[Run]) -> PresenceScore:
    return pool_presence(score_presence(r.boxes, r.groundtruth, r.state == 0) for r in runs)


def _episodes_cell(eps: list[Episode], attr: str, names: bool) -> str:
    hit = sum(getattr(e, attr) for e in eps)
    if not names:
        return f"{hit}/{len(eps)}"
    return (f"{hit}/{len(eps)} "
            f"({', '.join(e.sequence + ('' if getattr(e, attr) else ' ✗') for e in eps)})")


def goal_row(label: str, mine: list[Run], base: list[Run], names: bool = False,
             extra: str = "", shared_only: bool = False) -> str:
    """One row of the goals: episodes flagged and found again, hidden frames claimed, false
    alarms, presence, P@20 / AUC beside the same runs without re-acquisition (with
    ``shared_only``, on the shared sequences alone: the clips are too short to score)."""
    eps = [e for r in mine for e in occlusion_episodes(r)]
    fa, good = false_alarms(mine)
    pres = _presence(mine)
    if shared_only:
        mine_scored = [r for r in mine if not r.clip]
        base = [r for r in base if not r.clip]
    else:
        mine_scored = mine
    p, a = _scores(mine_scored)
    plain = "–"
    if base:
        pb, ab = _scores(base)
        plain = f"{pb:.3f} / {ab:.3f}"
    return (f"| {label} | {_episodes_cell(eps, 'flagged', names)} | "
            f"{_episodes_cell(eps, 'found', names)} | {sum(e.false_claims for e in eps)} | "
            f"{1000 * fa / max(good, 1):.1f} ({fa}/{good}) | {pres.precision:.3f} / "
            f"{pres.recall:.3f} / {pres.f_score:.3f} | {pres.tracking_f:.3f} | {p:.3f} / {a:.3f}"
            f" ({plain}) |{extra}")


GOAL_HEADER = ("| 1. losses flagged within 3 frames | 1. found again within 10 frames | hidden "
               "frames claimed tracking | 1. not tracking per 1,000 good frames | 3. presence "
               "P / R / F | 3. tracking F (VOT-LT) | 2. P@20 / AUC (re-acquisition off) |")


def report(runs: list[Run], plain: list[Run], args: argparse.Namespace) -> None:
    print(f"`python benchmarks/track_state.py {' '.join(sys.argv[1:])}`".replace(" `", "`"))
    print(f"{time.strftime('%Y-%m-%d')}, {describe()}; overrides "
          f"{args.set or 'none (the presets as shipped)'}\n")
    print("The 9 shared sequences and the 3 real occlusion clips:\n")
    print(f"| preset {GOAL_HEADER} 6. ECE | ms / frame (median) |")
    print("| --- " * (GOAL_HEADER.count("|") + 2) + "|")
    for preset in args.presets:
        mine = [r for r in runs if r.preset == preset and not r.loss]
        base = [r for r in plain if r.preset == preset and not r.loss]
        _, ece = reliability(*_confidences(mine))
        ms = 1000 * np.median(np.concatenate([r.seconds[1:] for r in mine]))
        print(goal_row(f"`{preset}`", mine, base, names=True, extra=f" {ece:.3f} | {ms:.1f} |",
                       shared_only=True))
    made = sorted({r.loss for r in runs if r.loss})
    if made:
        print(f"\nMade losses of {args.losses} frames on the 9 shared sequences "
              "(`arcf.eval.losses`), per kind, and every episode pooled (the clips' and the "
              "made ones; presence and P@20 / AUC over all those runs):\n")
        print(f"| preset | kind {GOAL_HEADER}")
        print("| --- " * (GOAL_HEADER.count("|") + 1) + "|")
        for preset in args.presets:
            for kind in [*made, "all"]:
                mine = [r for r in runs if r.preset == preset and (r.loss == kind or (
                    kind == "all" and (r.loss or r.clip)))]
                base = [r for r in plain if r.preset == preset and (r.loss == kind or (
                    kind == "all" and (r.loss or r.clip)))]
                if mine:
                    print(goal_row(f"`{preset}` | {kind}", mine, base))
    print("\nReliability (all presets pooled; a frame counts as a hit when its box overlaps "
          "the target, IoU > 0):\n")
    rows, ece = reliability(*_confidences(runs))
    print("| confidence | frames | mean confidence | fraction with IoU > 0 |")
    print("| --- | ---: | ---: | ---: |")
    print("\n".join(rows))
    print(f"\nExpected calibration error, pooled: {ece:.3f}")
    if args.fit:
        print(f"\nConfidence model fitted on the {args.fit_on} runs (StateParams):\n")
        print("\n".join(fit([r for r in runs if args.fit_on == "all" or not r.loss],
                             args.features)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", type=lambda s: s.split(","), default=list(PRESETS))
    ap.add_argument("--set", action="append", type=parse_override, metavar="KEY=VALUE",
                    help="override a parameter of every preset, e.g. --set state.probes=3")
    ap.add_argument("--fit", action="store_true", help="fit the confidence model too")
    ap.add_argument("--tune", action="store_true",
                    help="tune the state's thresholds of the presets without re-acquisition")
    ap.add_argument("--fit-on", choices=("real", "all"), default="real",
                    help="fit on the real runs (default: the made losses then test it) or on "
                    "all of them")
    ap.add_argument("--features", type=lambda s: tuple(s.split(",")), default=FEATURES,
                    help="the features --fit uses (the others weigh 0; default all: "
                    f"{','.join(FEATURES)})")
    ap.add_argument("--losses", type=int, default=0, metavar="N",
                    help="also run the shared sequences with made losses of N frames")
    ap.add_argument("--kinds", type=lambda s: tuple(s.split(",")), default=KINDS,
                    help=f"the kinds of made loss (default {','.join(KINDS)})")
    ap.add_argument("--cache", type=Path, help="keep runs in this folder and reuse them")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    unknown = set(args.kinds) - set(KINDS)
    if unknown:
        ap.error(f"unknown kinds {sorted(unknown)}; choose from {', '.join(KINDS)}")
    if set(args.features) - set(FEATURES):
        ap.error(f"unknown features {sorted(set(args.features) - set(FEATURES))}; choose from "
                 f"{', '.join(FEATURES)}")
    overrides = dict(args.set or [])
    runs = all_runs(args.presets, overrides, args.jobs, cache=args.cache)
    # the paper's tracker beside each ARCF preset (the Siamese ones and the hybrid take no
    # overrides: they have no plain version)
    from arcf.presets import PRESETS as ARCF_PRESETS

    arcf_presets = [p for p in args.presets if p in ARCF_PRESETS]
    off = {**overrides, "state.reacquire": False}
    plain = all_runs(arcf_presets, off, args.jobs, cache=args.cache)
    if args.losses:
        runs += all_runs(args.presets, overrides, args.jobs, args.kinds, args.losses,
                         args.cache)
        plain += all_runs(arcf_presets, off, args.jobs, args.kinds, args.losses, args.cache)
    report(runs, plain, args)
    if args.tune:
        print("\nThe state's thresholds tuned on the replayed runs (sequences, clips and made "
              "losses):\n")
        for preset in arcf_presets:
            print("\n".join(tune(runs, preset)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""One-pass evaluation runs: any preset (with overrides) over a dataset or a subset of it.

Layout of a run, compatible with the published results so the same scoring code reads both::

    <out>/<label>/<Dataset>/<sequence>.txt          x,y,w,h per frame (1-based pixel frame)
    <out>/<label>/<Dataset>/<sequence>_time.txt     tracker seconds per frame (no decoding)
    <out>/<label>/<Dataset>/<sequence>_details.csv  peak, psr, aberrance, aberrance_release, scale,
                                                     confidence, state (0 tracking, 1 coasting,
                                                     2 lost: ``STATE_CODES``)
    <out>/<label>/<Dataset>/<sequence>_map_diff.txt release-form map difference (like the authors')
    <out>/<label>/<Dataset>/fps.json                sequence -> FPS

``<Dataset>`` is ``UAV123_10fps``, ``DTB70``, ``UAVDT`` (the published folders' names) or the
dataset's own name. A sequence counts as done when its box file exists; the box file is written
last (atomically), so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from ..state import STATE_CODES
from .datasets import Sequence
from .results import write_results

#: Folder names of the published results, so our runs sit beside them in the same layout.
DATASET_FOLDERS = {"uav123_10fps": "UAV123_10fps", "dtb70": "DTB70", "uavdt": "UAVDT"}

#: Threads per worker process: one, since the workers themselves fill the cores.
_PIN = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


@dataclass(frozen=True)
class TrackerSpec:
    """A preset plus overrides, and the label its results are filed under."""

    preset: str
    overrides: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""

    @property
    def name(self) -> str:
        if self.label:
            return self.label
        extra = "_".join(f"{k}-{v}" for k, v in sorted(self.overrides.items()))
        return f"{self.preset}_{extra}" if extra else self.preset


@dataclass(frozen=True)
class SequenceRunInfo:
    sequence: str
    dataset: str
    frames: int
    seconds: float
    skipped: bool = False

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else float("nan")


def dataset_folder(dataset: str) -> str:
    return DATASET_FOLDERS.get(dataset, dataset)


def result_dir(out: Path, spec: TrackerSpec, dataset: str) -> Path:
    return Path(out) / spec.name / dataset_folder(dataset)


def is_done(out: Path, spec: TrackerSpec, seq: Sequence) -> bool:
    return (result_dir(out, spec, seq.dataset) / f"{seq.name}.txt").is_file()


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(text)
    os.replace(tmp, path)


def run_one(spec: TrackerSpec, seq: Sequence, out: Path) -> SequenceRunInfo:
    """Track one sequence (OPE) and write its files. Runs inside a worker process."""
    import cv2

    from ..registry import create_tracker
    from ..run import run_sequence

    cv2.setNumThreads(1)
    tracker = create_tracker(spec.preset, **dict(spec.overrides))
    # decoding is not part of the tracker's time
    run = run_sequence(tracker, (seq.read_frame(i) for i in range(len(seq))), seq.init_box)
    times = run.times
    details = [(r.peak, r.psr, r.aberrance, r.aberrance_release, r.scale, r.confidence,
                STATE_CODES[r.state]) for r in run.results]
    folder = result_dir(out, spec, seq.dataset)
    folder.mkdir(parents=True, exist_ok=True)
    np.savetxt(folder / f"{seq.name}_time.txt", np.array(times), fmt="%.6f")
    d = np.array(details)
    header = "peak,psr,aberrance,aberrance_release,scale,confidence,state"
    np.savetxt(folder / f"{seq.name}_details.csv", d, fmt="%.7g", delimiter=",", header=header,
               comments="")
    np.savetxt(folder / f"{seq.name}_map_diff.txt", d[:, 3], fmt="%.7g")
    part = folder / f"{seq.name}.txt.part"
    write_results(part, run.boxes)
    os.replace(part, folder / f"{seq.name}.txt")  # last: marks the sequence done
    return SequenceRunInfo(seq.name, seq.dataset, len(seq), float(sum(times)))


class Progress:
    """A one-line progress report with frames/s and ETA, on stderr (no extra dependency)."""

    def __init__(self, total_frames: int, label: str, stream: Any = None) -> None:
        self.total = max(total_frames, 1)
        self.label = label
        self.done = 0
        self.start = time.monotonic()
        self.stream = stream if stream is not None else sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def update(self, frames: int, note: str) -> None:
        self.done += frames
        elapsed = time.monotonic() - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else float("nan")
        line = (f"{self.label}: {self.done}/{self.total} frames ({100 * self.done / self.total:.0f}"
                f"%), {rate:.1f} frames/s, ETA {_fmt_seconds(eta)} - {note}")
        end = "" if self.tty else "\n"
        prefix = "\r\033[K" if self.tty else ""
        print(prefix + line, end=end, file=self.stream, flush=True)

    def close(self) -> None:
        if self.tty:
            print(file=self.stream, flush=True)


def _fmt_seconds(s: float) -> str:
    if not np.isfinite(s):
        return "?"
    n = round(s)
    if n >= 3600:
        return f"{n // 3600}:{n % 3600 // 60:02d}:{n % 60:02d}"
    return f"{n // 60}:{n % 60:02d}"


def run_experiment(
    spec: TrackerSpec,
    sequences: Iterable[Sequence],
    out: str | os.PathLike[str],
    *,
    jobs: int = 2,
    resume: bool = True,
    progress: bool = True,
    on_done: Callable[[SequenceRunInfo], None] | None = None,
) -> list[SequenceRunInfo]:
    """Run ``spec`` over ``sequences`` (a process per sequence, ``jobs`` at a time).

    Sequences already done are skipped when ``resume``; ``fps.json`` is rewritten from the
    per-frame times of every finished sequence, so a resumed run still reports all of them.
    A sequence that fails (e.g. a corrupt frame) is reported and the others go on; the first
    failure is raised at the end.
    """
    out = Path(out)
    seqs = list(sequences)
    todo = [s for s in seqs if not (resume and is_done(out, spec, s))]
    infos = [SequenceRunInfo(s.name, s.dataset, len(s), 0.0, skipped=True)
             for s in seqs if s not in todo]
    bar = Progress(sum(len(s) for s in todo), spec.name) if progress and todo else None
    failures: list[tuple[str, BaseException]] = []
    if todo:
        saved = {k: os.environ.get(k) for k in _PIN}
        os.environ.update({k: "1" for k in _PIN})  # spawned workers import NumPy with these
        try:
            ctx = get_context("spawn")
            with ProcessPoolExecutor(max_workers=max(1, jobs), mp_context=ctx) as pool:
                pending = {pool.submit(run_one, spec, s, out): s for s in todo}
                while pending:
                    finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in finished:
                        seq = pending.pop(fut)
                        try:
                            info = fut.result()
                        except BaseException as exc:
                            failures.append((seq.name, exc))
                            if bar:
                                bar.update(len(seq), f"{seq.name} FAILED: {exc}")
                            continue
                        infos.append(info)
                        if on_done:
                            on_done(info)
                        if bar:
                            bar.update(info.frames, f"{seq.name} {info.fps:.1f} FPS")
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
            if bar:
                bar.close()
    _write_fps(out, spec, {s.dataset for s in seqs})
    if failures:
        first, cause = failures[0]
        raise RuntimeError(f"{len(failures)} sequence(s) failed, first {first}: {cause}") from cause
    return infos


def _write_fps(out: Path, spec: TrackerSpec, datasets: Iterable[str]) -> None:
    for ds in datasets:
        folder = result_dir(out, spec, ds)
        if not folder.is_dir():
            continue
        fps = {}
        for t in sorted(folder.glob("*_time.txt")):
            name = t.name[: -len("_time.txt")]
            if (folder / f"{name}.txt").is_file():
                times = np.loadtxt(t, ndmin=1)
                fps[name] = round(float(len(times) / times.sum()), 3) if times.sum() > 0 else None
        _atomic_write_text(folder / "fps.json", json.dumps(fps, indent=1) + "\n")

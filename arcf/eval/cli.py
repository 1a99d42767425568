"""``arcf eval``: run trackers over the benchmarks and score result folders.

    arcf eval run --preset arcf-h --dataset uav123_10fps --out results
    arcf eval run --preset arcf-h --set aberrance=release --label arcf-h_release --dataset dtb70
    arcf eval score results/arcf-h/UAV123_10fps $ARCF_DATA/published_results/UAV123_10fps/\
        groundtruth
    arcf eval failure results/arcf-h/UAV123_10fps $ARCF_DATA/published_results/UAV123_10fps/\
        groundtruth --plot failure.png
    arcf eval presence results/arcf-h/UAV123_10fps $ARCF_DATA/published_results/UAV123_10fps/\
        groundtruth
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..data import data_root
from ..errors import ARCFError
from ..registry import ALL_PRESETS, preset_params
from .datasets import DatasetError, load_dataset
from .metrics import DatasetScore
from .results import ResultsError, read_fps, score_folder
from .runner import TrackerSpec, dataset_folder, result_dir, run_experiment

DATASETS = ("uav123_10fps", "dtb70", "uavdt")


def _sequence_filter(text: str | None) -> list[str] | None:
    return [s for s in text.split(",") if s] if text else None


def cmd_run(args: argparse.Namespace) -> int:
    overrides: dict[str, Any] = dict(args.set or [])
    try:
        preset_params(args.preset, **overrides)  # fail before any process starts
    except ARCFError as exc:
        raise SystemExit(f"arcf eval run: {exc}") from exc
    spec = TrackerSpec(args.preset, overrides, args.label or "")
    wanted = _sequence_filter(args.sequences)
    root = Path(args.data) if args.data else data_root()
    status = 0
    for ds in args.dataset:
        try:
            seqs = load_dataset(ds, root=root / ds if not Path(ds).is_dir() else None)
        except DatasetError as exc:
            print(f"arcf eval run: skipping {ds}: {exc}", file=sys.stderr)
            status = 1
            continue
        if wanted:
            seqs = [s for s in seqs if s.name in wanted]
        if not seqs:
            continue
        try:
            infos = run_experiment(spec, seqs, args.out, jobs=args.jobs, resume=not args.fresh,
                                   progress=not args.quiet)
        except RuntimeError as exc:
            print(f"arcf eval run: {exc}", file=sys.stderr)
            status = 1
            continue
        folder = result_dir(Path(args.out), spec, seqs[0].dataset)
        ran = [i for i in infos if not i.skipped]
        print(f"{spec.name} on {dataset_folder(seqs[0].dataset)}: {len(ran)} run, "
              f"{len(infos) - len(ran)} already done -> {folder}", file=sys.stderr)
        gt = root / "published_results" / dataset_folder(seqs[0].dataset) / "groundtruth"
        if gt.is_dir():
            names = [s.name for s in seqs]
            title = f"{spec.name} / {dataset_folder(seqs[0].dataset)}"
            _print_score(score_folder(folder, gt, sequences=names), read_fps(folder), title)
            from .presence import score_folder_presence

            _print_presence(score_folder_presence(folder, gt, sequences=names), title)
    return status


def _print_score(score: DatasetScore, fps: dict[str, float], title: str) -> None:
    print(f"## {title} ({score.convention} convention)\n")
    print("| sequence | P@20 | AUC | FPS |\n| --- | --- | --- | --- |")
    for name, s in score.sequences.items():
        f = fps.get(name)
        print(f"| {name} | {s.precision20:.3f} | {s.auc:.3f} | {'' if f is None else f'{f:.1f}'} |")
    print(f"| **mean** | **{score.precision20:.3f}** | **{score.auc:.3f}** | |\n")


def cmd_score(args: argparse.Namespace) -> int:
    try:
        score = score_folder(args.results, args.groundtruth,
                             sequences=_sequence_filter(args.sequences),
                             convention=args.convention)
        fps = read_fps(args.results)
    except (ResultsError, DatasetError, ValueError, FileNotFoundError) as exc:
        raise SystemExit(f"arcf eval score: {exc}") from exc
    _print_score(score, fps, str(args.results))
    return 0


def cmd_recording(args: argparse.Namespace) -> int:
    """Score the sessions of an ``arcf-record`` recording (``arcf.eval.recording``)."""
    from .recording import read_recording, score_recording

    try:
        scores = score_recording(args.recording, args.groundtruth, session=args.session,
                                 convention=args.convention)
        sessions = read_recording(args.recording)
    except (DatasetError, ValueError, FileNotFoundError) as exc:
        raise SystemExit(f"arcf eval recording: {exc}") from exc
    except ImportError as exc:
        raise SystemExit("arcf eval recording: needs the mcap package (pip install mcap)"
                         ) from exc
    print("| session | stream | frames with a box | precision@20 | AUC |\n"
          "| --- | --- | --- | --- | --- |")
    for sid, score in scores.items():
        rec = sessions[sid]
        print(f"| {sid} | {rec.stream_id} | {rec.tracked}/{score.n_frames} | "
              f"{score.precision20:.3f} | {score.auc:.3f} |")
    return 0


def cmd_failure(args: argparse.Namespace) -> int:
    """How well the run's track states flag its failures (``arcf.eval.failure``)."""
    from .failure import pool, pr_curve, score_folder_failures

    try:
        per = score_folder_failures(args.results, args.groundtruth,
                                    sequences=_sequence_filter(args.sequences), delay=args.delay)
    except (ResultsError, DatasetError, ValueError, FileNotFoundError) as exc:
        raise SystemExit(f"arcf eval failure: {exc}") from exc
    print(f"## Failure detection: {args.results} (flagged: coasting or lost; recall within "
          f"{args.delay} frames)\n")
    print("| sequence | failure frames | recall | precision | false alarms / 1,000 good | "
          "episodes flagged | median delay |\n| --- | --- | --- | --- | --- | --- | --- |")
    for name, s in [*((n, r.score) for n, r in per.items()),
                    ("**all**", pool(r.score for r in per.values()))]:
        print(f"| {name} | {s.failure_frames} | {s.recall_at:.3f} | {s.precision:.3f} | "
              f"{s.false_alarms_per_1000:.1f} | {s.episodes - s.missed_episodes}/{s.episodes} | "
              f"{s.median_delay:.0f} |")
    curve = pr_curve({n: 1.0 - r.confidence for n, r in per.items()},
                     {n: r.failure for n, r in per.items()}, {n: r.good for n, r in per.items()},
                     thresholds=[1.0 - t for t in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)],
                     delay=args.delay)
    print("\nThe confidence alone, flagged below each threshold:\n")
    print("| confidence < | recall | precision | false alarms / 1,000 good |\n| --- | --- | --- "
          "| --- |")
    for point in curve:
        print(f"| {1.0 - point.threshold:.1f} | {point.recall_at:.3f} | {point.precision:.3f} |"
              f" {point.false_alarms_per_1000:.1f} |")
    if args.plot:
        from .report import plot_failure_curve

        try:
            written = plot_failure_curve(curve, args.plot, title=str(args.results))
        except ImportError as exc:
            raise SystemExit(f"arcf eval failure: {exc}") from exc
        print(f"\nwrote {written}", file=sys.stderr)
    return 0


def _print_presence(per: dict[str, Any], title: str) -> None:
    from .presence import pool

    print(f"## Target presence: {title} (reported present: state `tracking`)\n")
    print("| sequence | frames | target visible | reported present | presence P / R / F | "
          "tracking P / R / F (VOT-LT) |\n| --- | --- | --- | --- | --- | --- |")
    for name, s in [*per.items(), ("**all**", pool(per.values()))]:
        print(f"| {name} | {s.frames} | {s.visible} | {s.reported} | {s.precision:.3f} / "
              f"{s.recall:.3f} / {s.f_score:.3f} | {s.tracking_precision:.3f} / "
              f"{s.tracking_recall:.3f} / {s.tracking_f:.3f} |")
    print()


def cmd_presence(args: argparse.Namespace) -> int:
    """Whether the run says its target is there when it is (``arcf.eval.presence``)."""
    from .presence import score_folder_presence

    try:
        per = score_folder_presence(args.results, args.groundtruth,
                                    sequences=_sequence_filter(args.sequences))
    except (ResultsError, DatasetError, ValueError, FileNotFoundError) as exc:
        raise SystemExit(f"arcf eval presence: {exc}") from exc
    if not per:
        raise SystemExit(f"arcf eval presence: no result files in {args.results}")
    _print_presence(per, str(args.results))
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from .paper import build_report

    try:
        doc = build_report(out=Path(args.out), doc=Path(args.doc), img=Path(args.img),
                           data=Path(args.data) if args.data else None, jobs=args.jobs,
                           progress=not args.quiet)
    except ImportError as exc:
        raise SystemExit(f"arcf eval report: {exc}") from exc
    print(f"arcf eval report: wrote {doc}", file=sys.stderr)
    return 0


def add_parser(sub: argparse._SubParsersAction[Any], parse_override: Any) -> None:
    ev = sub.add_parser("eval", help="run and score trackers on UAV123@10fps, DTB70, UAVDT")
    esub = ev.add_subparsers(dest="eval_command", required=True)

    r = esub.add_parser("run", help="one-pass evaluation of a preset over datasets (resumable)",
                        description="One-pass evaluation: init on each sequence's first "
                        "ground-truth box, never re-initialise. A process per sequence.")
    r.add_argument("--preset", default="arcf-hc", choices=sorted(ALL_PRESETS))
    r.add_argument("--set", action="append", type=parse_override, metavar="KEY=VALUE",
                   help="override a parameter, e.g. --set aberrance=release or "
                   "--set state.reacquire=true")
    r.add_argument("--label", help="results folder name (default: preset + overrides)")
    r.add_argument("--dataset", nargs="+", default=list(DATASETS),
                   help="dataset names (uav123_10fps, dtb70, uavdt) or dataset folders")
    r.add_argument("--sequences", help="comma-separated subset of sequence names")
    r.add_argument("--data", help="data root (default $ARCF_DATA or ../shared/data)")
    r.add_argument("--out", default="results", help="results root (default ./results)")
    r.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    r.add_argument("--fresh", action="store_true", help="rerun sequences already done")
    r.add_argument("--quiet", action="store_true", help="no progress line")
    r.set_defaults(func=cmd_run)

    s = esub.add_parser("score", help="score a folder of result files against ground truth")
    s.add_argument("results", help="folder of <sequence>.txt result files")
    s.add_argument("groundtruth", help="folder of <sequence>.txt ground-truth files")
    s.add_argument("--convention", choices=("toolkit", "clean"), default="toolkit")
    s.add_argument("--sequences", help="comma-separated subset")
    s.set_defaults(func=cmd_score)

    rc = esub.add_parser("recording", help="score the sessions of an arcf-record recording")
    rc.add_argument("recording", nargs="+", help="the recording's MCAP file(s)")
    rc.add_argument("groundtruth", help="ground-truth file (line k + 1 = frame_seq k)")
    rc.add_argument("--session", help="only this session (default: every session)")
    rc.add_argument("--convention", choices=("toolkit", "clean"), default="toolkit")
    rc.set_defaults(func=cmd_recording)

    f = esub.add_parser("failure", help="how well a run's track states flag its failures")
    f.add_argument("results", help="an arcf eval run folder (<sequence>.txt and _details.csv)")
    f.add_argument("groundtruth", help="folder of <sequence>.txt ground-truth files")
    f.add_argument("--sequences", help="comma-separated subset")
    f.add_argument("--delay", type=int, default=3,
                   help="frames a flag may lag a failure frame and still catch it (default 3)")
    f.add_argument("--plot", help="write the confidence's precision-recall curve (PNG)")
    f.set_defaults(func=cmd_failure)

    pr = esub.add_parser(
        "presence", help="precision, recall and F-score of the target's presence (VOT-LT)",
        description="A frame is reported present when the run's state is tracking. Presence: "
        "right when the box overlaps the visible target; tracking (VOT-LT): each reported "
        "frame scores its IoU.")
    pr.add_argument("results", help="an arcf eval run folder (<sequence>.txt and _details.csv)")
    pr.add_argument("groundtruth", help="folder of <sequence>.txt ground-truth files")
    pr.add_argument("--sequences", help="comma-separated subset")
    pr.set_defaults(func=cmd_presence)

    rp = esub.add_parser(
        "report",
        help="regenerate docs/results.md: the paper's tables and plots, ours vs published",
        description="Runs our presets (both aberrance formulations) on every local sequence "
        "(resumable), scores them and the published trackers, and writes the Markdown report "
        "with precision/success plots, Table 2 and the per-frame map-difference figure.",
    )
    rp.add_argument("--out", default="results", help="results root (runs cached here)")
    rp.add_argument("--doc", default="docs/results.md")
    rp.add_argument("--img", default="docs/img")
    rp.add_argument("--data", help="data root (default $ARCF_DATA or ../shared/data)")
    rp.add_argument("--jobs", type=int, default=2)
    rp.add_argument("--quiet", action="store_true")
    rp.set_defaults(func=cmd_report)

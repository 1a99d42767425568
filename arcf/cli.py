"""Command line: ``arcf track`` runs a tracker over a folder of frames.

Examples::

    arcf track ../shared/data/dtb70/Animal3/img --box 506,174,50,50 -o animal3.txt
    arcf track frames/ --init-from groundtruth.txt --preset arcf-h --video overlay.mp4
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from . import __version__
from .errors import ARCFError
from .eval.datasets import DatasetError
from .eval.datasets import list_frames as dataset_frames
from .registry import ALL_PRESETS, create_tracker
from .run import track_frames


def list_frames(folder: Path) -> list[Path]:
    try:
        return list(dataset_frames(folder))
    except DatasetError as exc:
        raise SystemExit(f"arcf track: {exc}") from exc


def read_frames(paths: Sequence[Path]) -> Iterator[np.ndarray]:
    for p in paths:
        frame = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if frame is None:
            raise SystemExit(f"arcf track: cannot decode image {p}")
        if frame.dtype != np.uint8:  # 16-bit PNG and the like
            frame = cv2.convertScaleAbs(frame, alpha=255.0 / max(float(frame.max()), 1.0))
        if frame.ndim == 3 and frame.shape[2] == 4:
            frame = cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
        yield frame


def parse_box(text: str) -> tuple[float, float, float, float]:
    parts = [p for p in text.replace(",", " ").replace("\t", " ").split() if p]
    if len(parts) != 4:
        raise argparse.ArgumentTypeError(f"a box is four numbers x,y,w,h; got {text!r}")
    try:
        x, y, w, h = (float(p) for p in parts)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"a box is four numbers x,y,w,h; got {text!r}") from exc
    return x, y, w, h


def parse_override(text: str) -> tuple[str, object]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"overrides are KEY=VALUE, got {text!r}")
    key, value = text.split("=", 1)
    try:
        parsed: object = json.loads(value)
    except json.JSONDecodeError:
        parsed = value
    return key.strip(), parsed


def draw(frame: np.ndarray, box: Sequence[float], text: str) -> np.ndarray:
    """The frame with the box (1-based coordinates) and a caption drawn on it."""
    out = frame if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    out = out.copy()
    x, y, w, h = box
    p0 = (round(x - 1), round(y - 1))
    p1 = (round(x - 1 + w), round(y - 1 + h))
    cv2.rectangle(out, p0, p1, (0, 255, 255), 2)
    cv2.putText(out, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 4, cv2.LINE_AA)
    cv2.putText(out, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def cmd_track(args: argparse.Namespace) -> int:
    paths = list_frames(Path(args.frames))
    if args.box is not None:
        box = args.box
    elif args.init_from is not None:
        box = parse_box(Path(args.init_from).read_text().splitlines()[0])
    else:
        raise SystemExit("arcf track: give the initial box with --box x,y,w,h or --init-from FILE")
    if args.frames_limit:
        paths = paths[: args.frames_limit]
    overrides = dict(args.set or [])
    try:
        tracker = create_tracker(args.preset, colornames_path=args.colornames, **overrides)
    except ARCFError as exc:
        raise SystemExit(f"arcf track: {exc}") from exc

    out = open(args.output, "w") if args.output else sys.stdout  # noqa: SIM115
    details = open(args.details, "w") if args.details else None  # noqa: SIM115
    if details:
        details.write("frame,x,y,w,h,peak,psr,aberrance,aberrance_release,scale,confidence,"
                      "state,seconds\n")
    writer = None
    if args.video:
        Path(args.video).parent.mkdir(parents=True, exist_ok=True)
    if args.overlay_dir:
        Path(args.overlay_dir).mkdir(parents=True, exist_ok=True)
    total = 0.0
    n = 0
    try:
        for i, (frame, result, seconds) in enumerate(
                track_frames(tracker, read_frames(paths), box)):
            path = paths[i]
            total += seconds
            n += 1
            x, y, w, h = result.box
            out.write(f"{x:.2f},{y:.2f},{w:.2f},{h:.2f}\n")
            if details:
                details.write(
                    f"{result.frame_index},{x:.3f},{y:.3f},{w:.3f},{h:.3f},{result.peak:.5f},"
                    f"{result.psr:.3f},{result.aberrance:.6f},{result.aberrance_release:.6f},"
                    f"{result.scale:.5f},{result.confidence:.4f},{result.state.value},"
                    f"{seconds:.6f}\n"
                )
            if args.video or args.overlay_dir:
                caption = (f"{args.preset} #{result.frame_index} {result.state.value} "
                           f"{result.confidence:.2f}")
                img = draw(frame, result.box, caption)
                if args.video:
                    if writer is None:
                        fourcc = cv2.VideoWriter.fourcc(*"mp4v")
                        writer = cv2.VideoWriter(
                            args.video, fourcc, args.fps, (img.shape[1], img.shape[0])
                        )
                    writer.write(img)
                if args.overlay_dir:
                    cv2.imwrite(str(Path(args.overlay_dir) / f"{path.stem}.jpg"), img)
    except ARCFError as exc:
        raise SystemExit(f"arcf track: {exc}") from exc
    finally:
        if writer is not None:
            writer.release()
        if out is not sys.stdout:
            out.close()
        if details:
            details.close()
    print(
        f"arcf track: {n} frames with {args.preset}, {n / total:.1f} FPS (tracker only)",
        file=sys.stderr,
    )
    return 0


def cmd_models(args: argparse.Namespace) -> int:
    """Which networks the folder holds, checked file by file; 1 if a network's files differ or
    one is missing beside the others, or a ``--require``d network cannot run."""
    from .models import NETWORKS, ModelNotFoundError, model_paths, models_root

    root = Path(args.dir).expanduser() if args.dir else models_root()
    print(f"models folder: {root}")
    failed = False
    for network in NETWORKS:
        try:
            model_paths(network, root)
            print(f"  {network}: ok")
        except ModelNotFoundError as exc:
            failed |= exc.altered or network in args.require
            print(f"  {network}: {'BROKEN' if exc.altered else 'missing'}: {exc}")
    return 1 if failed else 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="arcf", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"arcf {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    t = sub.add_parser(
        "track",
        help="track one target through a folder of frames",
        description="Run a tracker over a folder of frames (sorted by name) from an initial box "
        "and write one x,y,w,h row per frame (1-based pixel coordinates, like the datasets).",
    )
    t.add_argument("frames", help="folder of frames (jpg/png/...), sorted naturally by name")
    t.add_argument("--box", type=parse_box, help="initial box x,y,w,h (1-based pixel frame)")
    t.add_argument("--init-from", help="annotation file whose first row is the initial box")
    t.add_argument("--preset", default="arcf-hc", choices=sorted(ALL_PRESETS))
    t.add_argument(
        "--set", action="append", type=parse_override, metavar="KEY=VALUE",
        help="override a preset parameter, e.g. --set aberrance=release --set gamma=0.5; "
        "a nested one by its dotted name, e.g. --set state.reacquire=true",
    )
    t.add_argument("-o", "--output", help="result file (default: standard output)")
    t.add_argument("--details",
                   help="CSV with per-frame signals, confidence, state, scale and time")
    t.add_argument("--video", help="write an annotated video (e.g. out.mp4)")
    t.add_argument("--overlay-dir", help="write annotated frames into this folder")
    t.add_argument("--fps", type=float, default=10.0, help="frame rate of --video (default 10)")
    t.add_argument("--frames-limit", type=int, default=0, help="track only the first N frames")
    t.add_argument("--colornames", help="path of cn_norm_32768x10.npy (else $ARCF_COLORNAMES)")
    t.set_defaults(func=cmd_track)

    from .models import NETWORKS

    m = sub.add_parser(
        "models", help="check the Siamese networks' files (size and SHA-256)",
        description="List the networks the Siamese presets need and whether the models folder "
        "holds the published files. Exit status 1 if a network's folder holds a file that "
        "differs or lacks one, or a --require'd network is missing.")
    m.add_argument("--dir", help="the models folder (default: $ARCF_MODELS, else "
                   "../shared/models beside the data)")
    m.add_argument("--require", action="append", default=[], choices=sorted(NETWORKS),
                   help="fail unless this network can run")
    m.set_defaults(func=cmd_models)

    from .eval.cli import add_parser as add_eval_parser

    add_eval_parser(sub, parse_override)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())

"""Dataset loaders for the benchmarks of the ARCF paper, reading each dataset's own layout.

The loaders never copy or convert data: they resolve frame paths and parse the annotation files
where the user keeps them, so the same code runs the five sample sequences in the shared folder
and a full download (point ``root`` at the dataset's folder and every sequence appears).

Ground-truth boxes are kept exactly as the files give them: ``x, y, w, h`` in the 1-based pixel
frame of the MATLAB toolkits, NaN rows preserved (UAV123 marks out-of-view frames that way), so
that scoring with :mod:`arcf.eval.metrics` can apply the toolkit's own rules to them.

Layouts understood:

* **UAV123@10fps** -- ``data_seq/<video>/000001.jpg…``, ``anno/<sequence>.txt`` and the sequence
  table ``uav123_10fps_sequences.json`` (several sequences may share one video, each a 1-based
  inclusive frame range). The official archive's nested form ``data_seq/UAV123_10fps/<video>``
  and ``anno/UAV123_10fps/<sequence>.txt`` is accepted too.
* **DTB70** -- ``<sequence>/img/00001.jpg…`` and ``<sequence>/groundtruth_rect.txt``.
* **UAVDT** (single-object part) -- ``UAV-benchmark-S/<sequence>/img000001.jpg…`` and
  ``anno/<sequence>_gt.txt``.
* **Generic** -- any folder of frames (``.jpg``/``.jpeg``/``.png``/``.bmp``, natural name order)
  plus one annotation file, via :func:`load_sequence`.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from collections.abc import Callable, Iterable
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arcf.data import data_root

__all__ = [
    "DATASET_NAMES",
    "FRAME_EXTENSIONS",
    "UAV123_MAX_MISSING_ROWS",
    "DatasetError",
    "Sequence",
    "canonical_dataset_name",
    "list_frames",
    "load_dataset",
    "load_dtb70",
    "load_sequence",
    "load_uav123_10fps",
    "load_uavdt",
    "read_annotation",
    "read_boxes",
]

#: Image extensions a generic frame folder may hold (compared case-insensitively).
FRAME_EXTENSIONS: tuple[str, ...] = (".jpg", ".jpeg", ".png", ".bmp")

#: How many trailing annotation rows a UAV123 sequence may lack before it is an error. When the
#: annotation file is shorter than the table's frame range by at most this many rows, the frames
#: are truncated to the annotated count (with a warning): the MATLAB toolkit scores ``size(anno,
#: 1)`` frames, so unannotated trailing frames never count. A larger gap means a wrong table or a
#: wrong file and is reported instead of silently scoring a different sequence. (No sequence of
#: the shipped samples needs it: ``anno/truck4_1.txt`` looks one row short to ``wc -l`` only
#: because its last row has no newline; it has all 193 rows of frames 1..193.)
UAV123_MAX_MISSING_ROWS = 5

#: Canonical dataset names understood by :func:`load_dataset`.
DATASET_NAMES: tuple[str, ...] = ("uav123_10fps", "dtb70", "uavdt")

UAV123_TABLE_NAME = "uav123_10fps_sequences.json"

_ALIASES: dict[str, str] = {
    "uav12310fps": "uav123_10fps",
    "dtb70": "dtb70",
    "dtb": "dtb70",
    "uavdt": "uavdt",
    "uavdtsot": "uavdt",
    "uavdts": "uavdt",
}

_SEPARATORS = re.compile(r"\s*,\s*|\s+")


class DatasetError(ValueError):
    """A dataset on disk does not match its layout: missing files, malformed or short rows."""


@dataclass(frozen=True, eq=False)
class Sequence:
    """One annotated video: frame paths in order and one ground-truth row per frame.

    ``groundtruth`` is float64 of shape ``(len(frames), 4)`` holding ``x, y, w, h`` in the 1-based
    pixel frame of the annotation files; rows the dataset leaves unannotated are NaN. Equality is
    identity (``eq=False``) because comparing arrays element-wise has no single truth value.
    """

    name: str
    frames: tuple[Path, ...]
    groundtruth: np.ndarray
    dataset: str

    def __post_init__(self) -> None:
        gt = np.asarray(self.groundtruth, dtype=np.float64)
        if gt.ndim != 2 or gt.shape[1] != 4:
            raise DatasetError(f"{self.name}: ground truth must have shape (n, 4), got {gt.shape}")
        if gt.shape[0] != len(self.frames):
            raise DatasetError(
                f"{self.name}: {len(self.frames)} frames but {gt.shape[0]} ground-truth rows"
            )
        if len(self.frames) == 0:
            raise DatasetError(f"{self.name}: a sequence needs at least one frame")
        gt.setflags(write=False)  # frozen in spirit too: shared sequences must not drift
        object.__setattr__(self, "groundtruth", gt)
        object.__setattr__(self, "frames", tuple(Path(p) for p in self.frames))

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def init_box(self) -> tuple[float, float, float, float]:
        """The first frame's ground truth, the box an OPE run initialises the tracker with."""
        x, y, w, h = (float(v) for v in self.groundtruth[0])
        return (x, y, w, h)

    def read_frame(self, index: int) -> np.ndarray:
        """Decode frame ``index`` (0-based) as a BGR uint8 image.

        ``cv2.imread`` returns ``None`` rather than raising on a missing or corrupt file; turning
        that into an error naming the file stops a tracker from crashing later on ``None``.
        """
        import cv2  # local: listing and scoring datasets must not pay for importing OpenCV

        path = self.frames[index]
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise DatasetError(f"cannot decode frame {index} of {self.name}: {path}")
        return image

    def __repr__(self) -> str:
        return f"Sequence(name={self.name!r}, dataset={self.dataset!r}, frames={len(self)})"


# --------------------------------------------------------------------------- annotation files


def read_boxes(
    path: str | os.PathLike[str],
    error: Callable[[str], Exception] = DatasetError,
) -> np.ndarray:
    """Parse a box file: one ``x, y, w, h`` row per line, as an ``(n, 4)`` float64 array.

    Values may be separated by commas, tabs or spaces (the datasets and published result files
    use all three); ``NaN`` is accepted in any case. Blank lines are skipped, which absorbs a
    trailing newline or its absence. A row that is not four numbers raises ``error`` naming the
    file and the 1-based line, so a broken file is found at once instead of scoring garbage.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise error(f"box file not found: {path}") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text file ({exc})") from None
    rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        tokens = _SEPARATORS.split(stripped)
        if len(tokens) != 4:
            raise error(
                f"{path}, line {lineno}: expected 4 values (x, y, w, h), got {len(tokens)}: "
                f"{stripped!r}"
            )
        try:
            rows.append([float(tok) for tok in tokens])
        except ValueError:
            raise error(f"{path}, line {lineno}: not a number in {stripped!r}") from None
    if not rows:
        raise error(f"{path}: no boxes in file")
    return np.asarray(rows, dtype=np.float64)


def read_annotation(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a ground-truth annotation file (see :func:`read_boxes`); errors are DatasetError."""
    return read_boxes(path, DatasetError)


# --------------------------------------------------------------------------- frames


def _natural_key(name: str) -> tuple[object, ...]:
    """Sort key treating digit runs as numbers, so ``2.jpg`` precedes ``10.jpg``."""
    return tuple(int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name))


def list_frames(folder: str | os.PathLike[str]) -> tuple[Path, ...]:
    """The image files of a folder in natural name order (zero-padded or not)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"frame folder not found: {folder}")
    names = [
        entry.name
        for entry in os.scandir(folder)
        if entry.is_file() and os.path.splitext(entry.name)[1].lower() in FRAME_EXTENSIONS
    ]
    if not names:
        raise DatasetError(f"no frames ({', '.join(FRAME_EXTENSIONS)}) in {folder}")
    return tuple(folder / name for name in sorted(names, key=_natural_key))


def _numbered_frames(folder: Path, names: Iterable[str]) -> tuple[Path, ...]:
    """Paths of the expected frame files, checking that every one exists.

    One directory listing answers all existence checks (tens of thousands of stat calls on a
    network drive would dominate loading a full benchmark).
    """
    if not folder.is_dir():
        raise DatasetError(f"frame folder not found: {folder}")
    present = set(os.listdir(folder))
    paths = []
    for name in names:
        if name not in present:
            raise DatasetError(f"missing frame file: {folder / name}")
        paths.append(folder / name)
    return tuple(paths)


def _count_images(folder: Path) -> int:
    return sum(
        1
        for entry in os.scandir(folder)
        if entry.is_file() and os.path.splitext(entry.name)[1].lower() in FRAME_EXTENSIONS
    )


def _check_counts(name: str, n_frames: int, annotation: Path, n_rows: int) -> None:
    if n_frames != n_rows:
        raise DatasetError(
            f"{name}: {n_frames} frames but {n_rows} annotation rows in {annotation}"
        )


# --------------------------------------------------------------------------- sequence filter


def _select(
    available: SequenceABC[str],
    wanted: Iterable[str] | None,
    dataset: str,
    where: Path,
    known_elsewhere: Iterable[str] = (),
    elsewhere_hint: str = "",
) -> list[str]:
    """Apply the user's ``sequences`` filter, keeping the user's order.

    Unknown names raise an error listing what exists, because a typo silently dropping a
    sequence would change a benchmark's mean without anyone noticing.
    """
    if wanted is None:
        return list(available)
    if isinstance(wanted, str):
        wanted = [wanted]
    wanted = list(wanted)
    have = set(available)
    elsewhere = set(known_elsewhere)
    unknown = [w for w in wanted if w not in have]
    if unknown:
        absent = [u for u in unknown if u in elsewhere]
        if absent and len(absent) == len(unknown):
            raise DatasetError(
                f"{dataset}: sequence(s) {', '.join(absent)} are known but {elsewhere_hint}"
            )
        raise DatasetError(
            f"{dataset}: unknown sequence(s) {', '.join(unknown)} under {where}; "
            f"available: {', '.join(available) if available else '(none)'}"
        )
    return list(dict.fromkeys(wanted))  # drop repeats, keep order


def _root(root: str | os.PathLike[str] | None, name: str) -> Path:
    path = data_root() / name if root is None else Path(root).expanduser()
    if not path.is_dir():
        raise DatasetError(f"{name}: dataset folder not found: {path}")
    return path


# --------------------------------------------------------------------------- UAV123@10fps


def _find_uav123_table(root: Path, table: str | os.PathLike[str] | None) -> Path:
    if table is not None:
        path = Path(table).expanduser()
        if not path.is_file():
            raise DatasetError(f"uav123_10fps: sequence table not found: {path}")
        return path
    # The table is not part of the official archive; fall back to the copy in the data root so
    # that pointing ``root`` at a fresh download works without extra arguments.
    for candidate in (root / UAV123_TABLE_NAME, data_root() / "uav123_10fps" / UAV123_TABLE_NAME):
        if candidate.is_file():
            return candidate
    raise DatasetError(
        f"uav123_10fps: no {UAV123_TABLE_NAME} in {root}; pass table=<path to the sequence table>"
    )


def _uav123_dirs(root: Path) -> tuple[list[Path], list[Path]]:
    """Candidate frame and annotation folders: flat layout first, the official nesting second."""
    return (
        [root / "data_seq", root / "data_seq" / "UAV123_10fps"],
        [root / "anno", root / "anno" / "UAV123_10fps"],
    )


def load_uav123_10fps(
    root: str | os.PathLike[str] | None = None,
    sequences: Iterable[str] | None = None,
    table: str | os.PathLike[str] | None = None,
    include_missing: bool = False,
) -> list[Sequence]:
    """Load UAV123@10fps sequences as the sequence table defines them.

    A sequence is frames ``start_frame..end_frame`` (1-based, inclusive) of its video folder and
    the rows of ``anno/<name>.txt``. By default only sequences whose video folder exists are
    listed, so a partial copy loads cleanly; ``include_missing=True`` (or naming a sequence in
    ``sequences``) demands the frames and reports the first missing file.

    If the annotation file is shorter than the frame range by at most
    :data:`UAV123_MAX_MISSING_ROWS` rows, the trailing unannotated frames are dropped with a
    warning (the toolkit scores only annotated frames); any other mismatch is an error.
    """
    root = _root(root, "uav123_10fps")
    table_path = _find_uav123_table(root, table)
    try:
        spec = json.loads(table_path.read_text(encoding="utf-8"))
        digits = int(spec.get("frame_name_digits", 6))
        ext = str(spec.get("frame_ext", "jpg")).lstrip(".")
        entries = [
            (str(s["name"]), str(s["video"]), int(s["start_frame"]), int(s["end_frame"]))
            for s in spec["sequences"]
        ]
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{table_path}: not a valid sequence table ({exc!r})") from None

    frame_dirs, anno_dirs = _uav123_dirs(root)

    def video_dir(video: str) -> Path | None:
        return next((d / video for d in frame_dirs if (d / video).is_dir()), None)

    by_name = {e[0]: e for e in entries}
    local = [e[0] for e in entries if video_dir(e[1]) is not None]
    available = [e[0] for e in entries] if include_missing else local
    chosen = _select(
        available,
        sequences,
        "uav123_10fps",
        root,
        known_elsewhere=by_name,
        elsewhere_hint=f"their frames are not under {root / 'data_seq'}",
    )

    result = []
    for name in chosen:
        _, video, start, end = by_name[name]
        if end < start:
            raise DatasetError(
                f"{table_path}: {name} ends (frame {end}) before it starts ({start})"
            )
        folder = video_dir(video) or frame_dirs[0] / video
        anno = next((d / f"{name}.txt" for d in anno_dirs if (d / f"{name}.txt").is_file()), None)
        if anno is None:
            raise DatasetError(f"uav123_10fps: annotation not found: {anno_dirs[0] / name}.txt")
        gt = read_annotation(anno)
        n_frames = end - start + 1
        if gt.shape[0] < n_frames <= gt.shape[0] + UAV123_MAX_MISSING_ROWS:
            warnings.warn(
                f"uav123_10fps/{name}: {anno} has {gt.shape[0]} rows for frames {start}..{end} "
                f"({n_frames}); scoring only the {gt.shape[0]} annotated frames",
                stacklevel=2,
            )
            end = start + gt.shape[0] - 1
        else:
            _check_counts(f"uav123_10fps/{name}", n_frames, anno, gt.shape[0])
        frames = _numbered_frames(folder, (f"{i:0{digits}d}.{ext}" for i in range(start, end + 1)))
        result.append(Sequence(name, frames, gt, "uav123_10fps"))
    return result


# --------------------------------------------------------------------------- DTB70


def load_dtb70(
    root: str | os.PathLike[str] | None = None,
    sequences: Iterable[str] | None = None,
) -> list[Sequence]:
    """Load DTB70 sequences: every folder holding ``groundtruth_rect.txt`` and ``img/``.

    Frames are expected as ``img/00001.jpg`` onwards, one per annotation row; the first missing
    one is named, and extra images in ``img/`` are reported as a count mismatch.
    """
    root = _root(root, "dtb70")
    available = sorted(
        (p.name for p in root.iterdir() if (p / "groundtruth_rect.txt").is_file()),
        key=_natural_key,
    )
    return _numbered_sequences("dtb70", root, available, sequences, lambda name: (
        root / name / "groundtruth_rect.txt", root / name / "img", "{:05d}.jpg"))


# --------------------------------------------------------------------------- UAVDT


def load_uavdt(
    root: str | os.PathLike[str] | None = None,
    sequences: Iterable[str] | None = None,
) -> list[Sequence]:
    """Load UAVDT single-object sequences: ``UAV-benchmark-S/<seq>/img000001.jpg…`` and
    ``anno/<seq>_gt.txt``. Sequences are those with a frame folder (a partial download lists
    only what it holds); a frame folder without its annotation is an error.
    """
    root = _root(root, "uavdt")
    frames_root = root / "UAV-benchmark-S"
    if not frames_root.is_dir():
        raise DatasetError(f"uavdt: frame folder not found: {frames_root}")
    available = sorted((p.name for p in frames_root.iterdir() if p.is_dir()), key=_natural_key)
    return _numbered_sequences("uavdt", root, available, sequences, lambda name: (
        root / "anno" / f"{name}_gt.txt", frames_root / name, "img{:06d}.jpg"))


def _numbered_sequences(
    dataset: str,
    root: Path,
    available: list[str],
    sequences: Iterable[str] | None,
    where: Callable[[str], tuple[Path, Path, str]],
) -> list[Sequence]:
    """The chosen sequences of a dataset whose frames are numbered from 1, one per annotation
    row (DTB70, UAVDT): ``where(name)`` is a sequence's annotation file, frame folder and frame
    name format. The first missing frame is named; extra images in the folder are reported as
    a count mismatch. One loop, so that both datasets check their folders alike."""
    result = []
    for name in _select(available, sequences, dataset, root):
        anno, folder, frame_name = where(name)
        gt = read_annotation(anno)
        frames = _numbered_frames(folder, (frame_name.format(i) for i in range(1, gt.shape[0] + 1)))
        _check_counts(f"{dataset}/{name}", _count_images(folder), anno, gt.shape[0])
        result.append(Sequence(name, frames, gt, dataset))
    return result


# --------------------------------------------------------------------------- generic


def load_sequence(
    frames: str | os.PathLike[str],
    annotation: str | os.PathLike[str],
    name: str | None = None,
    dataset: str = "generic",
) -> Sequence:
    """A sequence from any folder of frames (natural name order) and one annotation file.

    The frame and row counts must agree: guessing which end to trim would misalign boxes.
    """
    folder = Path(frames)
    paths = list_frames(folder)
    anno = Path(annotation)
    gt = read_annotation(anno)
    seq_name = name if name is not None else folder.name
    _check_counts(seq_name, len(paths), anno, gt.shape[0])
    return Sequence(seq_name, paths, gt, dataset)


# --------------------------------------------------------------------------- by name


def canonical_dataset_name(name: str) -> str | None:
    """Map an alias (``UAV123@10fps``, ``UAV123_10fps``, ``DTB70``...) to its canonical name.

    Returns None for anything else, including strings that look like paths (``./DTB70`` means
    that folder, not the default copy of the dataset).
    """
    if "/" in name or os.sep in name:
        return None
    return _ALIASES.get(re.sub(r"[^a-z0-9]", "", name.lower()))


def _detect_layout(path: Path) -> str | None:
    """Guess which dataset a folder holds from its layout (for ``load_dataset(<path>)``)."""
    if (path / UAV123_TABLE_NAME).is_file() or (path / "data_seq").is_dir():
        return "uav123_10fps"
    if (path / "UAV-benchmark-S").is_dir():
        return "uavdt"
    if path.is_dir() and any((p / "groundtruth_rect.txt").is_file() for p in path.iterdir()):
        return "dtb70"
    return None


_LOADERS: dict[str, Callable[..., list[Sequence]]] = {
    "uav123_10fps": load_uav123_10fps,
    "dtb70": load_dtb70,
    "uavdt": load_uavdt,
}


def load_dataset(
    name_or_path: str | os.PathLike[str],
    root: str | os.PathLike[str] | None = None,
    sequences: Iterable[str] | None = None,
) -> list[Sequence]:
    """Load a benchmark by name (``uav123_10fps``, ``dtb70``, ``uavdt`` and their usual spellings)
    from ``root`` (default ``data_root()/<name>``), or from a folder whose layout identifies it.

    ``sequences`` restricts the result to those names, in that order.
    """
    text = os.fspath(name_or_path)
    canonical = canonical_dataset_name(text) if isinstance(name_or_path, str) else None
    if canonical is None:
        path = Path(text).expanduser()
        if not path.is_dir():
            raise DatasetError(
                f"unknown dataset {text!r}: expected one of {', '.join(DATASET_NAMES)} "
                "or a dataset folder"
            )
        canonical = _detect_layout(path)
        if canonical is None:
            raise DatasetError(f"{path}: layout matches none of {', '.join(DATASET_NAMES)}")
        if root is not None and Path(root).expanduser().resolve() != path.resolve():
            raise DatasetError(f"both a dataset folder ({path}) and root={root} given")
        root = path
    return _LOADERS[canonical](root, sequences=sequences)

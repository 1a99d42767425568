"""The Siamese trackers' network files: where they are, and that they are the right ones.

The networks are files the project may not redistribute inside its wheel (they are Apache-2.0,
but 2.5 MB of weights trained elsewhere belong beside the code, like the datasets): a setting
names their folder, ``$ARCF_MODELS``, else ``../shared/models`` beside the checkout (the
data root's sibling). Nothing is downloaded at run time. Each file is checked against its size
and SHA-256 before OpenCV loads it; a missing or different file raises
:class:`ModelNotFoundError`, which says where to get it and what its checksum must be.

The folder holds one sub-folder per network, as the files are published:

* ``nanotrack_v2/``: NanoTrack v2's backbone and neck/head (Honglin Chu, GitHub
  ``HonglinChu/SiamTrackers``, ``NanoTrack/models/nanotrackv2/``, commit 248663f; the files
  OpenCV's tracker sample links to);
* ``vittrack/``: VitTrack (OpenCV GSoC 2023; OpenCV Zoo, ``models/object_tracking_vittrack/``).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

from .data import data_root

#: Environment variable naming the models folder (the one holding ``nanotrack_v2/``...).
MODELS_ENV = "ARCF_MODELS"


class ModelNotFoundError(FileNotFoundError):
    """A network file is missing, or is not the published file (size or SHA-256 differ).

    ``altered`` tells a folder not filled yet (the network's sub-folder absent) from a wrong,
    damaged or half-done copy (a file that differs, or missing beside its network's others)."""

    def __init__(self, message: str, altered: bool = False) -> None:
        super().__init__(message)
        self.altered = altered


@dataclass(frozen=True)
class ModelFile:
    """One published network file: its place under the models folder and its identity."""

    folder: str
    name: str
    size: int
    sha256: str


#: network -> its files, in the order OpenCV's tracker takes them
NETWORKS: dict[str, tuple[ModelFile, ...]] = {
    "nanotrack": (
        ModelFile("nanotrack_v2", "nanotrack_backbone_sim.onnx", 1_056_849,
                  "530bdd0cd00f19afab79a863e71ba71e3312395a5dc9151af675082bdaaa2fc4"),
        ModelFile("nanotrack_v2", "nanotrack_head_sim.onnx", 726_198,
                  "0d8c0637be849f092cc7236cae02e55c8b9455ebe37ba50601d6115db4247cd9"),
    ),
    "vittrack": (
        ModelFile("vittrack", "object_tracking_vittrack_2023sep.onnx", 714_726,
                  "2990f0b7cd44d92afa48cd97db6de7be113fc1d9594fddb74e2725c10478e91d"),
    ),
}

#: where each network's files are published
SOURCES = {
    "nanotrack": "https://github.com/HonglinChu/SiamTrackers, NanoTrack/models/nanotrackv2/ "
                 "(commit 248663f; Apache-2.0)",
    "vittrack": "https://github.com/opencv/opencv_zoo, models/object_tracking_vittrack/ "
                "(Apache-2.0)",
}

#: files already checked, by (path, size, mtime): a service starts many sessions
_checked: set[tuple[str, int, int]] = set()


def models_root() -> Path:
    """The models folder: ``$ARCF_MODELS`` if set, else ``models/`` beside the data root
    (``../shared/models`` beside a checkout)."""
    env = os.environ.get(MODELS_ENV)
    if env:
        return Path(env).expanduser()
    return data_root().parent / "models"


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _where_to_get(network: str, root: Path) -> str:
    files = "; ".join(f"{m.folder}/{m.name} ({m.size:,} bytes, sha256 {m.sha256})"
                      for m in NETWORKS[network])
    return (f"put {files} under {root} (or set {MODELS_ENV} to the folder holding them); "
            f"published at {SOURCES[network]}")


def model_paths(network: str, root: str | os.PathLike[str] | None = None) -> tuple[Path, ...]:
    """The checked paths of ``network``'s files under ``root`` (default :func:`models_root`).

    Raises :class:`ModelNotFoundError` if a file is missing or is not the published one.
    """
    if network not in NETWORKS:
        raise ValueError(f"unknown network {network!r}; one of {', '.join(NETWORKS)}")
    base = Path(root).expanduser() if root is not None else models_root()
    paths = []
    for m in NETWORKS[network]:
        path = base / m.folder / m.name
        try:
            stat = path.stat()
        except OSError:
            raise ModelNotFoundError(f"{network}: no file {path}; "
                                     + _where_to_get(network, base),
                                     altered=path.parent.is_dir()) from None
        key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
        if key not in _checked:
            if stat.st_size != m.size or _sha256(path) != m.sha256:
                raise ModelNotFoundError(f"{network}: {path} is not the published file (size "
                                         f"or SHA-256 differ); " + _where_to_get(network, base),
                                         altered=True)
            _checked.add(key)
        paths.append(path)
    return tuple(paths)

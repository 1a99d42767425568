"""The installed layout of the sources, as a tree of symbolic links, for static tools.

The repository keeps one folder per role (``arcf/``, ``service/``, ``schemas/``, ``adapters/``,
``loadtools/``); the wheel installs them all under ``arcf`` (pyproject's ``package-dir``). At
run time the editable install's import hook maps the names, but tools that read files instead
of importing them (mypy, mkdocstrings' griffe) look for ``arcf/service/``. This builds that
layout from links to the working tree, so new files appear without reinstalling and every
reported path leads back to the real file.

    python tools/linktree.py [DEST]      # default build/src; prints DEST
"""

from __future__ import annotations

import shutil
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def package_dirs(root: Path = ROOT) -> dict[str, str]:
    """pyproject's package-dir: package name -> folder."""
    project = tomllib.loads((root / "pyproject.toml").read_text())
    return dict(project["tool"]["setuptools"]["package-dir"])


def build(dest: Path = ROOT / "build" / "src", root: Path = ROOT) -> Path:
    """(Re)make ``dest`` so that ``dest/arcf`` is the installed ``arcf`` package; return dest."""
    mapping = package_dirs(root)
    if dest.exists():
        shutil.rmtree(dest)
    top = dest / "arcf"
    top.mkdir(parents=True)
    mapped = {name.split(".", 1)[1]: folder for name, folder in mapping.items() if "." in name}
    for entry in sorted((root / mapping["arcf"]).iterdir()):
        if entry.name != "__pycache__" and entry.name not in mapped:
            (top / entry.name).symlink_to(entry)
    for sub, folder in mapped.items():
        (top / sub).symlink_to(root / folder, target_is_directory=True)
    return dest


if __name__ == "__main__":
    print(build(Path(sys.argv[1]).resolve() if len(sys.argv) > 1 else ROOT / "build" / "src"))

"""Where the project finds data it may not redistribute (datasets, the Color Names table).

Nothing here is ever copied into the repository: paths are resolved at run time from environment
variables, falling back to the shared folder that sits beside a checkout (``../shared/data``).
"""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable naming the data root (the folder holding ``uav123_10fps/``, ``dtb70/``...).
DATA_ENV = "ARCF_DATA"
#: Environment variable naming the Color Names table file (``cn_norm_32768x10.npy``).
COLORNAMES_ENV = "ARCF_COLORNAMES"

_REPO_ROOT = Path(__file__).resolve().parent.parent


def data_root() -> Path:
    """The data root: ``$ARCF_DATA`` if set, else ``../shared/data`` beside the checkout.

    The fallback is tried relative to the repository first and then to the working directory,
    so both an editable install and a run from the project folder find the shared data.
    """
    env = os.environ.get(DATA_ENV)
    if env:
        return Path(env).expanduser()
    for base in (_REPO_ROOT, Path.cwd()):
        candidate = (base / ".." / "shared" / "data").resolve()
        if candidate.is_dir():
            return candidate
    return (_REPO_ROOT / ".." / "shared" / "data").resolve()


def default_colornames_path() -> Path:
    """The Color Names table: ``$ARCF_COLORNAMES`` if set, else ``<data root>/colornames/...``."""
    env = os.environ.get(COLORNAMES_ENV)
    if env:
        return Path(env).expanduser()
    return data_root() / "colornames" / "cn_norm_32768x10.npy"

"""Set up Prometheus multiprocess mode. Imports nothing from prometheus_client on purpose:
the directory must be in the environment before that library is first imported anywhere."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

MULTIPROC_ENV = "PROMETHEUS_MULTIPROC_DIR"


def prepare(path: str | os.PathLike[str] | None = None) -> Path:
    """Create or empty the metrics directory and export it to this process and its children."""
    p = Path(path) if path else Path(tempfile.mkdtemp(prefix="arcf-metrics-"))
    if p.exists():
        shutil.rmtree(p)
    p.mkdir(parents=True)
    os.environ[MULTIPROC_ENV] = str(p)
    return p

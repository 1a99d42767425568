"""MkDocs hook: the sources in their installed layout, for mkdocstrings.

The wheel installs ``service/``, ``schemas/``, ``adapters/`` and ``loadtools/`` as
``arcf.service``, ``arcf.schemas``, ... (pyproject's ``package-dir``). griffe reads files and
cannot follow the editable install's mapping, so before the build this makes ``build/src``, a
tree of links in the installed layout (``tools/linktree.py``), which mkdocs.yml gives the
python handler as its ``paths``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def _build_tree() -> None:
    spec = importlib.util.spec_from_file_location("_arcf_linktree", ROOT / "tools" / "linktree.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.build(ROOT / "build" / "src", ROOT)


def on_startup(command: str, dirty: bool, **kwargs: Any) -> None:
    _build_tree()

"""A pytest plugin (``-p sanitized_plugin``) that makes ``arcf.client.media._jpegregion`` the
sanitized build named by ``ARCF_SANITIZED_JPEGREGION`` before any test imports it
(``fuzz/sanitize.py`` runs the decoder's tests so)."""

from __future__ import annotations

import os
from pathlib import Path

from run import load_extension

load_extension(Path(os.environ["ARCF_SANITIZED_JPEGREGION"]))

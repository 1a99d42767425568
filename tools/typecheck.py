"""Type-check the installed package (``arcf`` and its roles) with mypy, as .ci/run does.

mypy reads files, so it is run on the installed layout (``tools/linktree.py``, in a temporary
folder); the paths it reports are mapped back to the repository's (``arcf/service/x.py`` ->
``service/x.py``). Settings: pyproject's ``[tool.mypy]``. Extra arguments go to mypy.

    python tools/typecheck.py
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from linktree import ROOT, build, package_dirs


def main(argv: list[str]) -> int:
    mapping = {name.replace(".", "/") + "/": folder + "/"
               for name, folder in package_dirs().items() if name != "arcf"}
    with tempfile.TemporaryDirectory(prefix="arcf-typecheck-") as tmp:
        tree = build(Path(tmp) / "src")
        run = subprocess.run(
            [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
             "--cache-dir", str(ROOT / ".mypy_cache"), "-p", "arcf", *argv],
            cwd=tree, capture_output=True, text=True)
    pattern = re.compile("^(" + "|".join(re.escape(k) for k in mapping) + ")", re.M)
    sys.stdout.write(pattern.sub(lambda m: mapping[m.group(1)], run.stdout))
    sys.stderr.write(run.stderr)
    return run.returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

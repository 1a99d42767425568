"""Type-check the installed package (``arcf`` and its roles), the benchmarks and the tools with
mypy, as .ci/run does.

mypy reads files, so it is run on the installed layout (``tools/linktree.py``, in a temporary
folder); the paths it reports are mapped back to the repository's (``arcf/service/x.py`` ->
``service/x.py``). Settings: pyproject's ``[tool.mypy]``. Extra arguments go to mypy.

    python tools/typecheck.py
"""

from __future__ import annotations

import os
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
    # scripts beside the package, which import it as installed
    scripts = [str(p) for folder in ("benchmarks", "tools", "fuzz", "docs/hooks")
               for p in sorted((ROOT / folder).glob("*.py"))]
    mapping[str(ROOT) + "/"] = ""
    with tempfile.TemporaryDirectory(prefix="arcf-typecheck-") as tmp:
        tree = build(Path(tmp) / "src")
        run = subprocess.run(
            [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
             "--cache-dir", str(ROOT / ".mypy_cache"), "arcf", *scripts, *argv],
            cwd=tree, capture_output=True, text=True, env={**os.environ, "MYPYPATH": str(tree)})
    pattern = re.compile("^(" + "|".join(re.escape(k) for k in mapping) + ")", re.M)
    sys.stdout.write(pattern.sub(lambda m: mapping[m.group(1)], run.stdout))
    sys.stderr.write(run.stderr)
    return run.returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

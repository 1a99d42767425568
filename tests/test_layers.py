"""The packages stay in their layers: the tracker library imports none of the others, the wire
contract nothing of the tracker or the server, the server neither the load tools nor the
evaluation toolkit. Checked on every import statement of every module (function-local ones
too), and by importing the server in a fresh interpreter."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: package -> the top-level names (or dotted prefixes) it must never import
FORBIDDEN = {
    "arcf": ("schemas", "service", "loadtools", "adapters"),
    "schemas": ("arcf", "service", "loadtools", "adapters"),
    "service": ("loadtools", "arcf.eval", "matplotlib", "adapters", "pymavlink"),
    # an adapter is a client of the service: its SDK and the schemas, not its internals
    "adapters": ("loadtools", "arcf", "matplotlib", "service.worker", "service.app",
                 "service.control"),
}


def imported(path: Path, root: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the module at ``path``."""
    dotted = ".".join(path.relative_to(root).with_suffix("").parts)
    if path.name == "__init__.py":
        dotted = dotted.rsplit(".", 1)[0] + ".__init__"
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the module's own package
                base = dotted.split(".")[: -node.level]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            out.append((node.lineno, name))
            out += [(node.lineno, f"{name}.{a.name}") for a in node.names]
    return out


def violations(package: str, root: Path = ROOT) -> list[str]:
    found = []
    for path in sorted((root / package).rglob("*.py")):
        for line, name in imported(path, root):
            for bad in FORBIDDEN[package]:
                if name == bad or name.startswith(bad + "."):
                    found.append(f"{path.relative_to(root)}:{line} imports {name}")
    return sorted(found)


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_stays_in_its_layer(package: str) -> None:
    assert violations(package) == []


def test_the_check_sees_relative_and_local_imports(tmp_path: Path) -> None:
    pkg = tmp_path / "service"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "bad.py").write_text("def f():\n    from arcf.eval import load_dataset\n"
                                "from loadtools import Fleet\n")
    (pkg / "worse.py").write_text("from ..loadtools import driver\n")
    assert violations("service", tmp_path) == [
        "service/bad.py:2 imports arcf.eval", "service/bad.py:2 imports arcf.eval.load_dataset",
        "service/bad.py:3 imports loadtools", "service/bad.py:3 imports loadtools.Fleet",
        "service/worse.py:1 imports loadtools", "service/worse.py:1 imports loadtools.driver"]


def test_the_server_loads_without_the_tools() -> None:
    probe = ("import sys, service.app, service.client\n"
             "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('loadtools', "
             "'matplotlib') or m.startswith('arcf.eval'))\n"
             "print(bad)")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120, check=True)
    assert out.stdout.strip() == "[]"

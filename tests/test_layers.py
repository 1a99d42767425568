"""The packages stay in their layers: the tracker library imports none of the others, the wire
contract nothing of the tracker or the server, the server neither the load tools nor the
evaluation toolkit. Checked on every import statement of every module (function-local ones
too), and by importing the server and an adapter in a fresh interpreter.

The repository keeps one folder per role; the wheel installs them under the one ``arcf``
namespace (pyproject's ``package-dir``): ``service/`` is ``arcf.service`` and so on."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _package_dirs() -> dict[str, str]:
    """The one declaration of the layout: pyproject's ``package-dir`` (package -> folder)."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return dict(project["tool"]["setuptools"]["package-dir"])


#: folder -> the package it installs as, read from pyproject (as tools/linktree.py does)
PACKAGE = {folder: package for package, folder in _package_dirs().items()}

#: the tracker library: ``arcf`` itself and every ``arcf.*`` that is not another role's package
LIBRARY = "arcf library"

#: folder -> the packages (dotted prefixes) its modules must never import
FORBIDDEN = {
    "arcf": ("arcf.schemas", "arcf.client", "arcf.service", "arcf.loadtools", "arcf.adapters"),
    "schemas": (LIBRARY, "arcf.client", "arcf.service", "arcf.loadtools", "arcf.adapters"),
    # the client side (SDK, media, CDR): shared by stations, adapters and the server, it knows
    # none of them; of the library, only the region a tracker reads (arcf.region)
    "client": (LIBRARY, "arcf.service", "arcf.loadtools", "arcf.adapters", "matplotlib"),
    "service": ("arcf.loadtools", "arcf.eval", "matplotlib", "arcf.adapters", "pymavlink"),
    # an adapter is a client of the service: the client package and the schemas, nothing of
    # the server
    "adapters": ("arcf.loadtools", LIBRARY, "matplotlib", "arcf.service"),
}

#: folder -> modules it may import although a rule above forbids their package
ALLOWED = {"client": ("arcf.region",)}


def is_library(name: str) -> bool:
    """Whether the module ``name`` is (part of) the tracker library. ``arcf`` itself counts:
    importing it for a name (``from arcf import create_tracker``) is importing the tracker."""
    if name != "arcf" and not name.startswith("arcf."):
        return False
    return not any(name == p or name.startswith(p + ".") for p in PACKAGE.values() if p != "arcf")


def imported(path: Path, root: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the module at ``path``."""
    parts = path.relative_to(root).with_suffix("").parts
    dotted = ".".join([PACKAGE.get(parts[0], parts[0]), *parts[1:]])
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


def forbids(bad: str, name: str) -> bool:
    if bad == LIBRARY:
        return is_library(name)
    return name == bad or name.startswith(bad + ".")


def violations(folder: str, root: Path = ROOT) -> list[str]:
    found = []
    for path in sorted((root / folder).rglob("*.py")):
        for line, name in imported(path, root):
            if folder == "arcf" and name == "arcf":
                continue  # the package's own __init__
            if any(forbids(bad, name) for bad in FORBIDDEN[folder]) and not any(
                    forbids(ok, name) for ok in ALLOWED.get(folder, ())):
                found.append(f"{path.relative_to(root)}:{line} imports {name}")
    return sorted(set(found))


@pytest.mark.parametrize("folder", sorted(FORBIDDEN))
def test_package_stays_in_its_layer(folder: str) -> None:
    assert violations(folder) == []


def test_every_role_has_its_rules() -> None:
    """A role folder added to pyproject's package-dir is held to rules here, or fails."""
    assert set(PACKAGE) - {"loadtools"} == set(FORBIDDEN)


def test_the_check_sees_relative_and_local_imports(tmp_path: Path) -> None:
    pkg = tmp_path / "service"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "bad.py").write_text("def f():\n    from arcf.eval import load_dataset\n"
                                "from arcf.loadtools import Fleet\n")
    (pkg / "worse.py").write_text("from ..loadtools import driver\n")
    assert violations("service", tmp_path) == [
        "service/bad.py:2 imports arcf.eval", "service/bad.py:2 imports arcf.eval.load_dataset",
        "service/bad.py:3 imports arcf.loadtools", "service/bad.py:3 imports arcf.loadtools.Fleet",
        "service/worse.py:1 imports arcf.loadtools",
        "service/worse.py:1 imports arcf.loadtools.driver"]


def test_the_library_is_every_arcf_module_but_the_other_roles() -> None:
    assert is_library("arcf") and is_library("arcf.tracker") and is_library("arcf.eval.cli")
    assert not is_library("arcf.schemas.codec") and not is_library("arcf.service")
    assert not is_library("arcfx") and not is_library("numpy")
    assert forbids(LIBRARY, "arcf.features.fhog") and not forbids(LIBRARY, "arcf.schemas")


def test_the_server_loads_without_the_tools(loaded_after: Callable[..., list[str]]) -> None:
    assert loaded_after("import arcf.service.app, arcf.client",
                        "arcf.loadtools", "matplotlib", "arcf.eval") == []


def test_clients_do_not_load_the_tracker(loaded_after: Callable[..., list[str]]) -> None:
    """``arcf`` loads its library lazily: the wire contract, the client SDK and an adapter
    start without the tracker's modules or Numba."""
    assert loaded_after("import arcf.schemas, arcf.client, arcf.adapters.mavlink",
                        "numba", "arcf.tracker", "arcf.features", "arcf.admm") == []


def test_the_wheel_installs_one_namespace() -> None:
    """Every package the wheel installs is ``arcf`` or under it (no ``service`` or
    ``schemas`` at the top of site-packages), and each role's folder is one of them."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert all(p == "arcf" or p.startswith("arcf.") for p in project["packages"])
    for folder in PACKAGE:
        subs = {p.parent.relative_to(ROOT).as_posix()
                for p in (ROOT / folder).rglob("__init__.py")}
        declared = {f for f in subs
                    if ".".join([PACKAGE[folder], *Path(f).parts[1:]]) in project["packages"]}
        assert declared == subs, f"{folder}: packages missing from pyproject"


@pytest.mark.integration
def test_the_built_wheel_holds_arcf_only(tmp_path: Path) -> None:
    """Built as pip builds it, from a copy of the sources (no earlier build/ to reuse): every
    file under ``arcf/`` (or the wheel's metadata), every module of every role's folder, the
    data the package reads at run time, and console scripts that point into ``arcf``."""
    import shutil
    import zipfile

    source = tmp_path / "src"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".git", ".venv*", "build", "site", "results", "__pycache__", "*.egg-info", ".*_cache"))
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                    str(tmp_path), str(source)], check=True, timeout=600,
                   capture_output=True)
    (wheel,) = tmp_path.glob("arcf-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    modules = {f"{PACKAGE[p.relative_to(ROOT).parts[0]].replace('.', '/')}/"
               + "/".join(p.relative_to(ROOT).parts[1:])
               for folder in PACKAGE for p in (ROOT / folder).rglob("*.py")
               if "__pycache__" not in p.parts}
    assert modules == {n for n in names if n.endswith(".py")}
    tops = {n.split("/", 1)[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"arcf"}
    for needed in ("arcf/features/tables/sse_amd_epyc.txt", "arcf/schemas/json/index.json",
                   "arcf/adapters/static/view.html", "arcf/service/app.py",
                   "arcf/loadtools/demo.py", "arcf/features/fhog/fused.py"):
        assert needed in names, needed
    (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    scripts = [line.split("=", 1)[1].strip()
               for line in zipfile.ZipFile(wheel).read(entry_points).decode().splitlines()
               if "=" in line]
    assert scripts and all(s.startswith("arcf.") or s.startswith("arcf:") for s in scripts)

"""Nothing received from the network is ever executed: no module of the library, the schemas,
the service, the adapters or the load tools imports a deserialiser that can run code (pickle
and its relatives), calls eval/exec/compile, loads YAML unsafely or lets NumPy unpickle.
Messages are msgpack decoded into plain values and validated by pydantic; images go to
OpenCV's decoders after a header check.

(multiprocessing's queues pickle the commands the main process itself builds from validated
messages; that is process-internal, never bytes from a socket, and not flagged here.)"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SOURCES = sorted(p for pkg in ("arcf", "schemas", "service", "loadtools", "adapters")
                 for p in (ROOT / pkg).rglob("*.py"))
UNSAFE_MODULES = {"pickle", "cPickle", "_pickle", "dill", "cloudpickle", "marshal", "shelve",
                  "jsonpickle"}
UNSAFE_CALLS = {"eval", "exec", "compile", "__import__"}


def problems(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        where = f"{path.name}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.Import):
            found += [f"{where} imports {a.name}" for a in node.names
                      if a.name.split(".")[0] in UNSAFE_MODULES]
        elif isinstance(node, ast.ImportFrom):
            if (node.module or "").split(".")[0] in UNSAFE_MODULES:
                found.append(f"{where} imports from {node.module}")
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else (
                func.attr if isinstance(func, ast.Attribute) else "")
            keywords = {k.arg: k.value for k in node.keywords}
            if isinstance(func, ast.Name) and name in UNSAFE_CALLS:
                found.append(f"{where} calls {name}()")
            if name in ("load", "load_all") and isinstance(func, ast.Attribute) and \
                    isinstance(func.value, ast.Name) and func.value.id == "yaml":
                found.append(f"{where} calls yaml.{name} (use yaml.safe_load)")
            allow = keywords.get("allow_pickle")
            if isinstance(allow, ast.Constant) and allow.value is True:
                found.append(f"{where} passes allow_pickle=True")
            if name in ("unpackb", "Unpacker") and "ext_hook" in keywords:
                found.append(f"{where} installs a msgpack ext_hook")
    return found


def test_sources_found() -> None:
    names = {p.name for p in SOURCES}
    assert {"codec.py", "worker.py", "control.py", "tracker.py"} <= names


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_nothing_from_the_network_is_executed(path: Path) -> None:
    assert problems(path) == []


def test_the_check_catches_what_it_looks_for(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("import pickle\nfrom marshal import loads\nimport yaml\nimport numpy as np\n"
                   "eval('1')\nyaml.load('a')\nnp.load('x', allow_pickle=True)\n")
    assert len(problems(bad)) == 5

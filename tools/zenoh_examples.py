"""Fetch zenoh-python's own example programs (``z_sub.py``, ``z_get.py``, ...) for the installed
``eclipse-zenoh``: its source package from PyPI, checked against the hash PyPI lists, and its
``examples/`` folder extracted. The wheels leave the examples out; the tests run them
unmodified (tests/service/test_zenoh_examples.py) as a user of Zenoh's tools would.

    python tools/zenoh_examples.py            # prints the examples' folder
    python tools/zenoh_examples.py --index https://pypi.org/simple

.ci/run calls it; the folder is ``$XDG_CACHE_HOME/arcf`` (``~/.cache/arcf``) unless
``ARCF_ZENOH_EXAMPLES`` names one.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import shutil
import sys
import tarfile
import urllib.request
from importlib.metadata import version
from pathlib import Path

SIMPLE_JSON = "application/vnd.pypi.simple.v1+json"  # PEP 691


def examples_dir(zenoh_version: str | None = None) -> Path:
    """Where the examples of ``zenoh_version`` (the installed one by default) are kept."""
    if os.environ.get("ARCF_ZENOH_EXAMPLES"):
        return Path(os.environ["ARCF_ZENOH_EXAMPLES"])
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "arcf" / f"zenoh-python-{zenoh_version or version('eclipse-zenoh')}" / "examples"


def fetch(index: str, zenoh_version: str, out: Path) -> Path:
    """Download the sdist of ``zenoh_version`` listed by ``index`` (PEP 691 JSON), check its
    sha256, and extract its ``examples/`` into ``out``; a folder already there is kept."""
    if (out / "z_sub.py").is_file():
        return out
    request = urllib.request.Request(f"{index.rstrip('/')}/eclipse-zenoh/",
                                     headers={"Accept": SIMPLE_JSON})
    with urllib.request.urlopen(request, timeout=60) as reply:
        files = json.load(reply)["files"]
    wanted = {f"eclipse_zenoh-{zenoh_version}.tar.gz", f"eclipse-zenoh-{zenoh_version}.tar.gz"}
    listed = [f for f in files if f["filename"] in wanted]
    if not listed:
        raise SystemExit(f"{index} lists no source package of eclipse-zenoh {zenoh_version}")
    sdist = listed[0]
    with urllib.request.urlopen(sdist["url"], timeout=120) as reply:
        data = reply.read()
    digest = hashlib.sha256(data).hexdigest()
    if digest != sdist["hashes"]["sha256"]:
        raise SystemExit(f"{sdist['filename']}: sha256 {digest}, PyPI lists "
                         f"{sdist['hashes']['sha256']}")
    root = sdist["filename"].removesuffix(".tar.gz").replace("eclipse-zenoh", "eclipse_zenoh")
    part = out.with_name(out.name + ".part")
    shutil.rmtree(part, ignore_errors=True)  # a run cut short
    out.parent.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        members = [m for m in tar.getmembers()
                   if m.name.startswith(f"{root}/examples/") and (m.isfile() or m.isdir())]
        for m in members:
            m.name = m.name.removeprefix(f"{root}/examples/")
        tar.extractall(part, members=[m for m in members if m.name], filter="data")
    part.rename(out)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--index", default="https://pypi.org/simple",
                    help="a PEP 691 package index (default: PyPI's)")
    ap.add_argument("--version", default=None,
                    help="eclipse-zenoh's version (default: the installed one)")
    args = ap.parse_args(argv)
    zenoh_version = args.version or version("eclipse-zenoh")
    print(fetch(args.index, zenoh_version, examples_dir(zenoh_version)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

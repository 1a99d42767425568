#!/usr/bin/env python3
"""Prepare what an image build needs when no registry can be reached (air-gapped sites).

Two inputs replace the network during ``docker build``:

* a **base image** built from Debian packages with ``debootstrap --variant=minbase`` and
  ``docker import`` (Debian bookworm: Python 3.11, the version the image is made for), where
  ``python:3.11-slim-bookworm`` cannot be pulled, and beside it a **build image**, the same
  plus a C compiler and libjpeg-turbo's and Python's headers (``arcf-build:bookworm``, for
  the Dockerfile's build stage, which compiles the partial JPEG decoder), where
  ``python:3.11-bookworm`` cannot be pulled;
* a **wheelhouse** (``deploy/wheelhouse/``) with every Python package the image installs, for
  the image's Python and CPU whatever the host runs, so that ``pip install --no-index`` inside
  the build needs no index.

It also fills ``deploy/models/`` with the Siamese presets' network files (``nanotrack_v2/``,
``vittrack/``) from the models folder (``$ARCF_MODELS``, else ``../shared/models``), so that the
image carries them; the image's build checks each file's size and SHA-256 (``arcf models``).

Run on a machine that reaches PyPI and a Debian mirror (as root, for debootstrap); carry the
wheelhouse and ``docker save arcf-base:bookworm arcf-build:bookworm`` to the site if it is
elsewhere. Then::

    python3 deploy/offline.py                    # base image (if missing), wheelhouse, models
    docker-compose -f deploy/compose.yaml -f deploy/compose.local.yaml -p arcf up -d --build

Each step is skipped when its result is already there (``--force`` redoes it).
"""

from __future__ import annotations

import argparse
import filecmp
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WHEELHOUSE = ROOT / "deploy" / "wheelhouse"
MODELS = ROOT / "deploy" / "models"
BASE_TAG = "arcf-base:bookworm"
BUILD_TAG = "arcf-build:bookworm"
#: Debian bookworm's Python, which the Dockerfile's default base (python:3.11-slim) matches.
PYTHON_VERSION = "3.11"
#: python3-venv brings ensurepip (the image makes a virtualenv); passwd is in minbase already.
BASE_PACKAGES = ("python3", "python3-venv", "ca-certificates")
#: The build image's additions: what compiles client/media/_jpegregion.c (the image's runtime needs
#: none of it: the build stage copies libjpeg beside the module).
BUILD_PACKAGES = ("gcc", "libc6-dev", "libjpeg62-turbo-dev", "python3-dev")
IMAGE_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
#: manylinux tags the image's glibc (2.36) accepts, newest first, per CPU.
PLATFORMS = {
    "x86_64": ("manylinux_2_34_x86_64", "manylinux_2_28_x86_64", "manylinux_2_17_x86_64",
               "manylinux2014_x86_64"),
    "aarch64": ("manylinux_2_34_aarch64", "manylinux_2_28_aarch64", "manylinux_2_17_aarch64",
                "manylinux2014_aarch64"),
}


def log(msg: str) -> None:
    print(f"[offline] {msg}", flush=True)


def requirements() -> list[str]:
    """What ``pip install .[service]`` needs: the build backend, the runtime dependencies and
    the service extra, read from pyproject.toml (one list, no copy to keep in step)."""
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    project = meta["project"]
    return ["pip", *meta["build-system"]["requires"], *project["dependencies"],
            *project["optional-dependencies"]["service"]]


def build_wheelhouse(dest: Path, machine: str, force: bool) -> None:
    stamp = dest / ".requirements"
    wanted = "\n".join([PYTHON_VERSION, machine, *requirements()])
    if not force and stamp.is_file() and stamp.read_text() == wanted:
        log(f"wheelhouse up to date: {dest}")
        return
    for old in dest.glob("*.whl"):
        old.unlink()
    dest.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "--disable-pip-version-check",
           "--only-binary=:all:", "--python-version", PYTHON_VERSION,
           "--implementation", "cp", "--dest", str(dest)]
    for tag in PLATFORMS[machine]:
        cmd += ["--platform", tag]
    t0 = time.monotonic()
    subprocess.run([*cmd, *requirements()], check=True)
    stamp.write_text(wanted)
    size = sum(p.stat().st_size for p in dest.glob("*.whl"))
    log(f"wheelhouse: {len(list(dest.glob('*.whl')))} wheels, {size / 2**20:.0f} MiB, "
        f"{time.monotonic() - t0:.0f} s")


def models_source() -> Path:
    """Where the network files come from by default: ``$ARCF_MODELS``, else ``models/``
    beside the data root (``$ARCF_DATA``, else ``../shared/data``), as the package finds them."""
    if os.environ.get("ARCF_MODELS"):
        return Path(os.environ["ARCF_MODELS"]).expanduser()
    data = os.environ.get("ARCF_DATA")
    return (Path(data).expanduser() if data else ROOT.parent / "shared" / "data").parent / "models"


def copy_models(source: Path, dest: Path) -> None:
    """``dest`` made to hold exactly ``source``'s network files (``<network>/*.onnx``): the
    ones that differ copied, the ones gone from ``source`` removed (the build checks each)."""
    files = sorted(source.glob("*/*.onnx")) if source.is_dir() else []
    wanted = {dest / f.parent.name / f.name: f for f in files}
    for old in dest.glob("*/*"):
        if old not in wanted:
            old.unlink()
    for folder in dest.glob("*/"):
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
    if not files:
        log(f"no network files under {source}: the image will carry no Siamese models")
        return
    for target, src in wanted.items():
        if target.is_file() and filecmp.cmp(src, target, shallow=False):
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, target)
    log(f"models: {len(files)} files from {source} in {dest}")


def image_exists(tag: str) -> bool:
    return subprocess.run(["docker", "image", "inspect", tag], capture_output=True).returncode == 0


def build_base(tag: str, mirror: str, suite: str, force: bool,
               packages: tuple[str, ...] = BASE_PACKAGES) -> None:
    if not force and image_exists(tag):
        log(f"image present: {tag}")
        return
    if shutil.which("debootstrap") is None:
        sys.exit("debootstrap not found: apt-get install debootstrap")
    if os.geteuid() != 0:
        sys.exit("debootstrap needs root")
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="arcf-rootfs-", dir="/var/tmp") as tmp:
        rootfs = Path(tmp) / "rootfs"
        subprocess.run(["debootstrap", "--variant=minbase", f"--include={','.join(packages)}",
                        suite, str(rootfs), mirror], check=True, stdout=subprocess.DEVNULL)
        # what an image does not need: package lists and caches, documentation
        for sub in ("var/lib/apt/lists", "var/cache/apt", "usr/share/doc", "usr/share/man",
                    "usr/share/locale"):
            path = rootfs / sub
            if path.is_dir():
                shutil.rmtree(path)
                path.mkdir()
        (rootfs / "var/lib/apt/lists/partial").mkdir(parents=True)
        tar = subprocess.Popen(["tar", "-C", str(rootfs), "--numeric-owner", "-c", "."],
                               stdout=subprocess.PIPE)
        subprocess.run(["docker", "import",
                        "--change", "ENV LANG=C.UTF-8",
                        "--change", f"ENV PATH={IMAGE_PATH}",
                        "--change", 'CMD ["/bin/bash"]',
                        "--message", f"debootstrap --variant=minbase {suite} + "
                                     f"{' '.join(packages)}",
                        "-", tag], stdin=tar.stdout, check=True, stdout=subprocess.DEVNULL)
        assert tar.stdout is not None
        tar.stdout.close()
        if tar.wait() != 0:
            sys.exit("tar of the root filesystem failed")
    log(f"image {tag} built in {time.monotonic() - t0:.0f} s")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("steps", nargs="*", metavar="{base,wheels,models}",
                    help="what to prepare (default: all three)")
    ap.add_argument("--base-tag", default=BASE_TAG)
    ap.add_argument("--build-tag", default=BUILD_TAG)
    ap.add_argument("--mirror", default="http://deb.debian.org/debian")
    ap.add_argument("--suite", default="bookworm")
    ap.add_argument("--wheelhouse", type=Path, default=WHEELHOUSE)
    ap.add_argument("--models-from", type=Path, default=None,
                    help="the models folder to copy (default: $ARCF_MODELS, else ../shared/models)")
    ap.add_argument("--machine", default=platform.machine(), choices=sorted(PLATFORMS),
                    help="CPU of the image (default: this machine's)")
    ap.add_argument("--force", action="store_true", help="redo steps already done")
    args = ap.parse_args(argv)
    steps = args.steps or ["base", "wheels", "models"]
    if unknown := set(steps) - {"base", "wheels", "models"}:
        ap.error(f"unknown step(s): {', '.join(sorted(unknown))}")
    if "wheels" in steps:
        build_wheelhouse(args.wheelhouse, args.machine, args.force)
    if "models" in steps:
        copy_models(args.models_from or models_source(), MODELS)
    if "base" in steps:
        build_base(args.base_tag, args.mirror, args.suite, args.force)
        build_base(args.build_tag, args.mirror, args.suite, args.force,
                   BASE_PACKAGES + BUILD_PACKAGES)
    return 0


if __name__ == "__main__":
    sys.exit(main())

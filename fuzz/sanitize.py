"""Build the C region decoder (``client/media/_jpegregion.c``) with AddressSanitizer and
UndefinedBehaviorSanitizer, and run the decoder's tests, the seed corpus and a bounded fuzz
run of ``jpeg_region`` through that build.

    python fuzz/sanitize.py                 # build, tests, corpus, 60 s of fuzzing
    python fuzz/sanitize.py --seconds 600   # a longer fuzz run

clang builds it (Debian's ``clang``) with ``-fsanitize=address,undefined,fuzzer-no-link``:
the sanitizers stop at the first bad access or undefined operation in our C code (every UB
check is fatal: ``-fno-sanitize-recover``), and the fuzzer sees the C code's branches. The
Python interpreter is not sanitized, so atheris's ASan runtime (``asan_with_fuzzer.so``) is
preloaded into it; leak checking is off (CPython keeps its objects to the end). libjpeg itself
is the system's, not instrumented: its writes into our buffer are checked by the fuzz target's
guard bytes instead (``fuzz/targets.py``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SOURCE = ROOT / "client" / "media" / "_jpegregion.c"
#: the decoder's tests and the corpus replay, run on the sanitized build
TESTS = ["tests/service/test_region_decode.py", "tests/service/test_fuzz_corpus.py",
         "tests/service/test_jpegregion.py"]
FLAGS = ["-fPIC", "-O1", "-g", "-fno-omit-frame-pointer",
         "-fsanitize=address,undefined,fuzzer-no-link", "-fno-sanitize-recover=all"]


def build(out: Path) -> Path:
    """The sanitized extension module, in ``out``."""
    clang = shutil.which("clang")
    if clang is None:
        sys.exit("sanitize: no clang (Debian's clang package)")
    target = out / ("_jpegregion" + sysconfig.get_config_var("EXT_SUFFIX"))
    obj = out / "_jpegregion.o"
    subprocess.run([clang, *FLAGS, "-I", sysconfig.get_paths()["include"], "-c", str(SOURCE),
                    "-o", str(obj)], check=True)
    # linked without a runtime: the sanitizers' and the fuzzer's symbols come from the one
    # preloaded into Python (environment())
    subprocess.run([clang, "-shared", str(obj), "-ljpeg", "-o", str(target)], check=True)
    return target


def environment(extension: Path) -> dict[str, str]:
    import atheris

    return {**os.environ,
            "LD_PRELOAD": str(Path(atheris.path()) / "asan_with_fuzzer.so"),
            "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1:allocator_may_return_null=1",
            "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1",
            "ARCF_SANITIZED_JPEGREGION": str(extension),
            "PYTHONPATH": os.pathsep.join(filter(None, [str(HERE),
                                                        os.environ.get("PYTHONPATH")]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=int, default=60, help="of fuzzing jpeg_region (0: none)")
    ap.add_argument("--artifacts", type=Path, default=Path("fuzz-artifacts"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="arcf-sanitized-") as tmp:
        extension = build(Path(tmp))
        env = environment(extension)
        print(f"sanitized build: {extension}", flush=True)
        # the tests import the decoder through sanitized_plugin, which loads this build
        steps = [[sys.executable, "-m", "pytest", "-q", "-p", "sanitized_plugin", *TESTS],
                 [sys.executable, str(HERE / "run.py"), "--replay", "--extension",
                  str(extension)]]
        if args.seconds:
            steps.append([sys.executable, str(HERE / "run.py"), "jpeg_region", "--seconds",
                          str(args.seconds), "--extension", str(extension), "--artifacts",
                          str(args.artifacts.resolve())])
        for step in steps:
            print("$", " ".join(step[1:]), flush=True)
            if subprocess.run(step, cwd=ROOT, env=env).returncode != 0:
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

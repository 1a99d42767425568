"""Run the fuzz targets (``fuzz/targets.py``) with atheris, Google's coverage-guided Python
fuzzer (libFuzzer inside), from the seed corpus (``fuzz/corpus/<target>/``).

    python fuzz/run.py --all --seconds 20          # each target 20 s, one process each
    python fuzz/run.py jpeg_region --seconds 600   # one target; new inputs go to a work folder
    python fuzz/run.py --replay                    # every seed through every target, no fuzzer
    python fuzz/run.py jpeg_region --input crash-… # one input (a fuzzer's artifact) once

Coverage comes from atheris's instrumentation of the Python code under ``arcf`` (as it is
imported). The C region
decoder is instrumented when it is built for it (``fuzz/sanitize.py`` builds it with clang's
``-fsanitize=fuzzer-no-link,address,undefined`` and runs this with ``--extension``). Each
target prints libFuzzer's final figures (executions, coverage, corpus). A broken contract, a
crash, a timeout or a memory blow-up stops it and writes the input to ``--artifacts``; the
exit status is then non-zero.
"""

from __future__ import annotations

import argparse
import importlib.machinery
import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
CORPUS = HERE / "corpus"


def load_extension(path: Path) -> None:
    """Make ``arcf.client.media._jpegregion`` the module built at ``path`` (a sanitized build)."""
    name = "arcf.client.media._jpegregion"
    loader = importlib.machinery.ExtensionFileLoader(name, str(path))
    spec = importlib.util.spec_from_file_location(name, path, loader=loader)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    sys.modules[name] = module
    import arcf.client.media

    arcf.client.media._jpegregion = module


def replay() -> int:
    """Every seed through every target; the number of broken contracts."""
    from targets import TARGETS

    broken = 0
    for name, target in TARGETS.items():
        seeds = sorted((CORPUS / name).iterdir())
        for seed in seeds:
            try:
                target(seed.read_bytes())
            except Exception as exc:  # reported, counted
                broken += 1
                print(f"{name}/{seed.name}: {type(exc).__name__}: {exc}")
        print(f"{name}: {len(seeds)} seeds replayed")
    return broken


def run_input(name: str, path: Path, extension: Path | None) -> int:
    """One input through one target, as the fuzzer ran it: 0 when its contract holds."""
    if extension is not None:
        load_extension(extension)
    from targets import TARGETS

    try:
        TARGETS[name](path.read_bytes())
    except Exception as exc:  # the report is the point
        print(f"{name}/{path.name}: {type(exc).__name__}: {exc}")
        return 1
    print(f"{name}/{path.name}: contract kept")
    return 0


def fuzz_one(name: str, seconds: int, artifacts: Path, work: Path | None,
             extension: Path | None) -> int:
    """One target in this process (atheris takes the process over)."""
    import atheris

    # the targets, the project's modules and the ROS 2 bridge's CDR library, instrumented as
    # they are imported (instrumenting everything loaded, NumPy and OpenCV's Python included,
    # takes most of a minute per target)
    sys.modules.pop("targets", None)  # imported for the command line: import it again
    with atheris.instrument_imports(include=["targets", "arcf", "rosbags"]):
        if extension is not None:
            load_extension(extension)
        # the modules the targets import lazily
        import targets


    target = targets.TARGETS[name]
    work = work or Path(tempfile.mkdtemp(prefix=f"arcf-fuzz-{name}-"))
    work.mkdir(parents=True, exist_ok=True)
    artifacts.mkdir(parents=True, exist_ok=True)
    print(f"{name}: {seconds} s from {CORPUS / name}; new inputs in {work}", flush=True)
    argv = [sys.argv[0], str(work), str(CORPUS / name), f"-max_total_time={seconds}",
            "-timeout=20", "-rss_limit_mb=3072", "-max_len=262144", "-print_final_stats=1",
            f"-artifact_prefix={artifacts}/{name}-"]
    atheris.Setup(argv, target)
    atheris.Fuzz()
    return 0


def main(argv: list[str] | None = None) -> int:
    from targets import TARGETS

    names_all = list(TARGETS)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("targets", nargs="*", choices=[[], *names_all], metavar="TARGET",
                    help=f"one or more of: {', '.join(names_all)}")
    ap.add_argument("--all", action="store_true", help="every target, one after the other")
    ap.add_argument("--seconds", type=int, default=60, help="per target (default 60)")
    ap.add_argument("--artifacts", type=Path, default=Path("fuzz-artifacts"),
                    help="where a failing input is written (default ./fuzz-artifacts)")
    ap.add_argument("--work", type=Path, help="the folder new inputs go to (one target)")
    ap.add_argument("--extension", type=Path,
                    help="load the region decoder from this build (fuzz/sanitize.py's)")
    ap.add_argument("--replay", action="store_true", help="replay the seeds, no fuzzing")
    ap.add_argument("--input", type=Path, help="run one input through the one target named")
    args = ap.parse_args(argv)
    if args.replay:
        return 1 if replay() else 0
    names = names_all if args.all else args.targets
    if not names:
        ap.error("name a target or give --all")
    if args.input is not None:
        if len(names) != 1:
            ap.error("--input needs exactly one target")
        return run_input(names[0], args.input, args.extension)
    if len(names) == 1:
        return fuzz_one(names[0], args.seconds, args.artifacts.resolve(), args.work,
                        args.extension)
    failed = []
    for name in names:  # one process each: atheris runs one target per process
        cmd = [sys.executable, __file__, name, "--seconds", str(args.seconds),
               "--artifacts", str(args.artifacts.resolve())]
        if args.extension:
            cmd += ["--extension", str(args.extension)]
        if subprocess.run(cmd, env=os.environ).returncode != 0:
            failed.append(name)
    if failed:
        print(f"broken: {', '.join(failed)} (inputs in {args.artifacts})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.path.insert(0, str(HERE))
    sys.exit(main())

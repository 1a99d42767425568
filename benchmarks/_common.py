"""What the benchmarks share: the start of their command line.

Each benchmark is a script (``python benchmarks/NAME.py``) that imports this module from beside
it, as compare.py imports speed.py. The options most of them take, the tracker preset and the
frame rate, are declared here once, so that every ``--help`` spells, types and explains them
alike; each benchmark gives its own defaults.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any


def parser(doc: str | None, *, preset: str | None = None, fps: float | None = None,
           fps_help: str = "frames a second, per stream") -> argparse.ArgumentParser:
    """A benchmark's parser: the first line of ``doc`` (its module docstring) as the
    description, then ``--preset`` and ``--fps`` with these defaults; an option whose default
    is None is not offered."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0] if doc else None)
    if preset is not None:
        ap.add_argument("--preset", default=preset,
                        help="the tracker preset (a name arcf.registry knows)")
    if fps is not None:
        ap.add_argument("--fps", type=float, default=fps, help=fps_help)
    return ap


def spread(values: Sequence[float], fmt: str = "{:.0f}", unit: str = "") -> str:
    """``median unit (min–max)`` of repeated measurements, "–" for none."""
    if not values:
        return "–"
    low, mid, high = (fmt.format(v) for v in (min(values), statistics.median(values),
                                                 max(values)))
    return f"{mid}{unit} ({low}–{high})"


def write_trials(path: Path | None, machine: dict[str, Any], trials: list[Any]) -> None:
    """Every trial's figures, with the machine they ran on, as JSON at ``path`` (if any)."""
    if path is not None:
        path.write_text(json.dumps({"machine": machine, "trials": trials}, indent=2))


def header(script: str, argv: Sequence[str] | None, machine: dict[str, Any],
           details: str) -> None:
    """Print what a benchmark's table comes from: its command line (``argv``: the options
    given, None for the process's), then the date, the machine and ``details``."""
    given = " ".join(sys.argv[1:] if argv is None else argv)
    print(f"`python benchmarks/{script} {given}`".replace(" `", "`"))
    print(f"{time.strftime('%Y-%m-%d')}, {machine['cpu']} ({machine['nproc']} cores), "
          f"{machine['software']}; {details}\n")


def table(head: Sequence[str], rows: Iterable[Sequence[str]], note: str | None = None) -> None:
    """Print a Markdown table, then ``note`` (what its columns mean) under it."""
    print("| " + " | ".join(head) + " |")
    print("|" + " --- |" * len(head))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    if note:
        print(f"\n{note}")


def report(script: str, argv: Sequence[str] | None, details: str, head: Sequence[str],
           rows: Iterable[Sequence[str]], note: str | None, json_path: Path | None,
           trials: list[Any]) -> None:
    """A benchmark's whole output: :func:`header` on this machine, its :func:`table`, and
    every trial's figures at ``json_path`` (:func:`write_trials`)."""
    from arcf.loadtools.system import machine

    m = machine()
    header(script, argv, m, details)
    table(head, rows, note)
    write_trials(json_path, m, trials)

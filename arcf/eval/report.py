"""Report pieces: precision/success plots, Markdown tables and the paper's Table 2.

The module is a set of small composable functions rather than one ``write_report``: a benchmark
script picks the plots and tables it needs, and each function can be tested on its own.

Plots need matplotlib, an optional extra (``pip install "arcf[eval]"``). It is imported only
inside the plotting functions, and only its object-oriented API with the Agg canvas is used (no
``pyplot``): that draws without a display, never switches the backend of a caller's interactive
session and keeps no global figure state, so plots can be made from worker threads.

Table 2 of the paper ("average response-map difference", Eq. 2, lower is better) is reproduced
from the authors' per-frame files ``<sequence>_map_diff.txt`` (one value per frame, the first
frame 0 since there is no previous map). Two natural averages exist and they differ in the third
significant digit; measured on the 123 UAV123@10fps sequences of the published results:

=======  ===================================  ==================  ======
tracker  ``"pooled"`` (frames 2..n together)  ``"per_sequence"``  paper
=======  ===================================  ==================  ======
ARCF-H   0.010596 -> **0.0106**               0.010892 -> 0.0109  0.0106
BACF     0.013325 -> **0.0133**               0.013898 -> 0.0139  0.0133
=======  ===================================  ==================  ======

Only the pooled mean -- every frame after the first of every sequence weighted equally, so long
sequences count more -- reproduces the paper, so it is the default of
:func:`map_difference_mean`. (Pooling *with* the first-frame zeros gives 0.010561 / 0.013282,
which also rounds to the paper's figures, but those zeros are not measurements and are skipped.)
"""

from __future__ import annotations

import math
import os
from collections.abc import Collection, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from arcf.eval.metrics import PRECISION_THRESHOLDS, SUCCESS_THRESHOLDS, DatasetScore

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from arcf.eval.failure import CurvePoint
    from arcf.types import TrackResult

__all__ = [
    "MAP_DIFF_SUFFIX",
    "CurveKind",
    "MapDiffAverage",
    "legend_labels",
    "map_difference_files",
    "map_difference_mean",
    "markdown_table",
    "plot_failure_curve",
    "plot_map_difference",
    "plot_precision",
    "plot_success",
    "plot_track_signals",
    "ranked",
    "read_map_difference",
    "table2_markdown",
]

CurveKind = Literal["precision", "success"]
MapDiffAverage = Literal["pooled", "per_sequence"]

#: File-name ending of the per-frame response-map differences in a result folder.
MAP_DIFF_SUFFIX = "_map_diff.txt"

#: Twelve colours that stay distinguishable on white (the tab10 set plus black and gold);
#: combined with :data:`_LINESTYLES` they give 48 distinct curves.
_COLORS: tuple[str, ...] = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b",
    "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#000000", "#b8860b",
)  # fmt: skip
_LINESTYLES: tuple[str, ...] = ("-", "--", "-.", ":")
_LINEWIDTH = 1.3
_LINEWIDTH_OURS = 2.6
_DPI = 120
_INSTALL_HINT = 'plotting needs matplotlib, an optional extra: pip install "arcf[eval]"'


# --------------------------------------------------------------------------- plotting helpers


def _new_figure(width: float, height: float) -> Figure:
    """A figure on an Agg canvas, importing matplotlib only now (it is an optional extra)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError(_INSTALL_HINT) from exc
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def _style(names: Iterable[str]) -> dict[str, tuple[str, str]]:
    """Colour and line style per name, fixed by alphabetical position.

    Tying the style to the name set rather than to the ranking keeps a tracker's look the same
    on the precision and the success plot of one benchmark, where the rankings differ. The
    style index advances once per full colour cycle so that names 0 and 12 still differ.
    """
    out = {}
    for i, name in enumerate(sorted(set(names))):
        out[name] = (_COLORS[i % len(_COLORS)], _LINESTYLES[(i + i // len(_COLORS)) % 4])
    return out


def _save(fig: Figure, path: str | os.PathLike[str], dpi: int) -> Path:
    """Write a compact PNG (no metadata beyond the format's own), creating parent folders."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png", dpi=dpi, bbox_inches="tight", metadata={"Software": None})
    return out


def _legend(ax: Axes, n: int, inside_loc: str) -> None:
    """Legend inside the axes for a few curves, beside them when many would hide the data."""
    if n <= 8:
        ax.legend(loc=inside_loc, fontsize="small", framealpha=0.85)  # type: ignore[call-overload]
    else:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", frameon=False)


# --------------------------------------------------------------------------- precision / success


def _headline(score: DatasetScore, kind: CurveKind) -> float:
    if kind == "precision":
        return float(score.precision20)
    if kind == "success":
        return float(score.auc)
    raise ValueError(f"unknown curve kind {kind!r}; expected 'precision' or 'success'")


def ranked(scores: Mapping[str, DatasetScore], kind: CurveKind) -> list[tuple[str, float]]:
    """``(name, headline figure)`` best first: precision@20 or AUC, ties by name, NaN last.

    This is the order of the legend (and of drawing), as in the paper's plots, so the reader
    finds the ranking without comparing numbers.
    """
    items = [(name, _headline(s, kind)) for name, s in scores.items()]
    return sorted(items, key=lambda it: (math.isnan(it[1]), -np.nan_to_num(it[1]), it[0]))


def legend_labels(scores: Mapping[str, DatasetScore], kind: CurveKind) -> list[str]:
    """The legend entries ``"NAME [0.666]"`` in plotting order (see :func:`ranked`)."""
    return [
        f"{name} [{'n/a' if math.isnan(v) else f'{v:.3f}'}]" for name, v in ranked(scores, kind)
    ]


def _plot_curves(
    scores: Mapping[str, DatasetScore],
    path: str | os.PathLike[str],
    title: str,
    kind: CurveKind,
    ours: Collection[str],
    dpi: int,
) -> Path:
    if not scores:
        raise ValueError("no scores to plot")
    order = ranked(scores, kind)  # validates kind before matplotlib is touched
    if kind == "precision":
        x, xlabel, ylabel = PRECISION_THRESHOLDS, "Location error threshold (pixels)", "Precision"
        loc = "lower right"  # curves rise to the right: the empty corner is bottom right
    else:
        x, xlabel, ylabel = SUCCESS_THRESHOLDS, "Overlap threshold", "Success rate"
        loc = "lower left"  # curves fall to the right: the empty corner is bottom left
    labels = legend_labels(scores, kind)
    styles = _style(scores)
    fig = _new_figure(6.4 if len(scores) > 8 else 5.0, 4.0)
    ax = fig.add_subplot()
    for (name, _), label in zip(order, labels, strict=True):
        y = np.asarray(getattr(scores[name], kind), dtype=np.float64)
        if y.shape != x.shape:
            raise ValueError(f"{name}: {kind} curve has {y.shape[0]} points, expected {x.size}")
        colour, linestyle = styles[name]
        mine = name in ours
        ax.plot(
            x,
            y,
            color=colour,
            linestyle="-" if mine else linestyle,
            linewidth=_LINEWIDTH_OURS if mine else _LINEWIDTH,
            zorder=3 if mine else 2,
            label=label,
        )
    ax.set_xlim(float(x[0]), float(x[-1]))
    ax.set_ylim(0.0, 1.0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.grid(True, linestyle=":", linewidth=0.6, alpha=0.7)
    _legend(ax, len(scores), loc)
    fig.tight_layout()
    return _save(fig, path, dpi)


def plot_precision(
    scores: Mapping[str, DatasetScore],
    path: str | os.PathLike[str],
    title: str = "",
    *,
    ours: Collection[str] = frozenset(),
    dpi: int = _DPI,
) -> Path:
    """Precision plot (fraction of frames within t px, t = 0..50) of several trackers.

    One curve per tracker, legend ``"NAME [precision@20]"`` best first; trackers named in
    ``ours`` are drawn solid, thicker and on top so the paper's contribution stands out among a
    dozen baselines. Returns the PNG path.
    """
    return _plot_curves(scores, path, title, "precision", ours, dpi)


def plot_failure_curve(curve: Sequence[CurvePoint], path: str | os.PathLike[str], title: str = "",
                       *, dpi: int = _DPI) -> Path:
    """Failure detection by confidence (``arcf.eval.failure.pr_curve`` points): recall within
    the delay against false alarms per 1,000 good frames, each point labelled with its
    confidence threshold. Returns the PNG path."""
    fig = _new_figure(5.0, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    xs = [max(p.false_alarms_per_1000, 0.1) for p in curve]  # a log axis shows the low end
    ax.plot(xs, [p.recall_at for p in curve], marker="o", color=_COLORS[0])
    for x, p in zip(xs, curve, strict=True):
        ax.annotate(f"{1.0 - p.threshold:.1f}", (x, p.recall_at), textcoords="offset points",
                    xytext=(4, -10), fontsize=7)
    ax.axvline(2.0, color="0.6", linestyle=":", linewidth=1)
    ax.axhline(0.8, color="0.6", linestyle=":", linewidth=1)
    ax.set_xscale("log")
    ax.set_xlabel("false alarms per 1,000 frames of good tracking")
    ax.set_ylabel("failure frames flagged (recall)")
    ax.set_ylim(0, 1.02)
    ax.set_title(title or "failure detection (labels: confidence threshold)", fontsize=9)
    ax.grid(True, alpha=0.3)
    return _save(fig, path, dpi)


def plot_track_signals(runs: Mapping[str, Sequence[TrackResult]], overlap: Mapping[str, np.ndarray],
                       path: str | os.PathLike[str], title: str = "",
                       *, span: tuple[int, int] | None = None, shade: tuple[int, int] | None = None,
                       dpi: int = _DPI) -> Path:
    """What the tracker tells around a loss: per run (label -> its per-frame results), the
    overlap with the ground truth and the confidence, then PSR and the release's aberrance;
    the frames a run was coasting or lost shaded, each ``reacquired`` marked. ``span`` limits
    the frames shown, ``shade`` marks an interval (e.g. an occlusion). Returns the PNG path."""
    from arcf.state import TrackState

    fig = _new_figure(7.0, 5.6)
    axes = [fig.add_subplot(4, 1, i + 1) for i in range(4)]
    lo, hi = span or (0, max(len(r) for r in runs.values()))
    for i, (label, results) in enumerate(runs.items()):
        color = _COLORS[i % len(_COLORS)]
        frames = np.arange(len(results))[lo:hi]
        part = results[lo:hi]
        axes[0].plot(frames, overlap[label][lo:hi], color=color, label=label)
        axes[1].plot(frames, [r.confidence for r in part], color=color)
        axes[2].plot(frames, [r.psr for r in part], color=color)
        axes[3].plot(frames, [r.aberrance_release for r in part], color=color)
        for k, r in zip(frames, part, strict=True):
            if r.state is not TrackState.TRACKING:  # a strip per run under the overlap
                axes[0].axvspan(k - 0.5, k + 0.5, ymin=0.04 * i, ymax=0.04 * (i + 1),
                                color="#d62728" if r.state is TrackState.LOST else "#ffbf00",
                                linewidth=0)
            if r.reacquired:
                for ax in axes:
                    ax.axvline(k, color=color, linestyle="--", linewidth=1)
    names = ("overlap (IoU)", "confidence", "PSR", "aberrance")
    for ax, name in zip(axes, names, strict=True):
        ax.set_ylabel(name, fontsize=8)
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.set_xlim(lo, hi - 1)
        if shade:
            ax.axvspan(shade[0] - 0.5, shade[1] - 0.5, color="0.85", zorder=0)
    axes[0].set_ylim(0, 1)
    axes[1].set_ylim(0, 1.02)
    axes[0].legend(fontsize="small", loc="upper right", framealpha=0.85)
    axes[-1].set_xlabel("frame (strips: coasting amber, lost red; dashed: reacquired)",
                        fontsize=8)
    axes[0].set_title(title, fontsize=9)
    return _save(fig, path, dpi)


def plot_success(
    scores: Mapping[str, DatasetScore],
    path: str | os.PathLike[str],
    title: str = "",
    *,
    ours: Collection[str] = frozenset(),
    dpi: int = _DPI,
) -> Path:
    """Success plot (fraction of frames with overlap > t, t = 0..1) of several trackers.

    As :func:`plot_precision`, with the AUC as the legend figure. Returns the PNG path.
    """
    return _plot_curves(scores, path, title, "success", ours, dpi)


# --------------------------------------------------------------------------- tables


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _bold_if(text: str, best: bool) -> str:
    return f"**{text}**" if best else text


def _best(values: Iterable[float | None], digits: int, higher: bool) -> float | None:
    """The best value *as displayed*: two figures that print the same are both best."""
    shown = [round(v, digits) for v in values if v is not None and not math.isnan(v)]
    if not shown:
        return None
    return max(shown) if higher else min(shown)


def _is_best(v: float | None, best: float | None, digits: int) -> bool:
    return v is not None and best is not None and not math.isnan(v) and round(v, digits) == best


def _datasets(rows: Mapping[str, Mapping[str, object]]) -> list[str]:
    return list(dict.fromkeys(ds for per in rows.values() for ds in per))


def _markdown(header: Sequence[str], body: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in body]
    return "\n".join(lines) + "\n"


def markdown_table(
    rows: Mapping[str, Mapping[str, DatasetScore]],
    fps: Mapping[str, float | None] | None = None,
    *,
    note: bool = True,
) -> str:
    """Markdown table of precision@20 / AUC per dataset, their mean over datasets, and FPS.

    ``rows`` maps tracker -> dataset -> score; rows keep the mapping's order and columns the
    order in which datasets first appear. A tracker without a dataset gets "—" there and in the
    mean, since a mean over fewer datasets would not be comparable with the others. The mean
    column averages the per-dataset figures with equal weight per dataset (as the paper's
    "over the three datasets" comparisons do), not per sequence. FPS is blank when unknown (the
    per-sequence speeds of :func:`arcf.eval.results.read_fps` must be reduced by the caller,
    who knows whether they came from one machine).

    The best value per column is bold -- precision and AUC separately, compared as displayed
    (3 decimals), highest FPS. Scores of different conventions cannot share a table (their
    figures are not comparable) and raise ``ValueError``; with ``note`` a line below the table
    says which convention produced the figures, as every reported figure should.
    """
    if not rows:
        raise ValueError("no rows for the table")
    conventions = {s.convention for per in rows.values() for s in per.values()}
    if len(conventions) > 1:
        raise ValueError(f"scores of different conventions in one table: {sorted(conventions)}")
    datasets = _datasets(rows)
    fps = fps or {}

    def pair(per: Mapping[str, DatasetScore]) -> tuple[float | None, float | None]:
        if any(ds not in per for ds in datasets):
            return None, None
        return (
            float(np.mean([per[ds].precision20 for ds in datasets])),
            float(np.mean([per[ds].auc for ds in datasets])),
        )

    columns: list[dict[str, tuple[float | None, float | None]]] = [
        {
            t: (per[ds].precision20, per[ds].auc) if ds in per else (None, None)
            for t, per in rows.items()
        }
        for ds in datasets
    ]
    columns.append({t: pair(per) for t, per in rows.items()})
    speed = {t: _finite(fps.get(t)) for t in rows}
    best_speed = _best(speed.values(), 1, higher=True)

    body = []
    for tracker in rows:
        cells = [_cell(tracker)]
        for col in columns:
            best_p = _best((p for p, _ in col.values()), 3, higher=True)
            best_a = _best((a for _, a in col.values()), 3, higher=True)
            p, a = col[tracker]
            if p is None or a is None:
                cells.append("—")
                continue
            cells.append(
                f"{_bold_if(f'{p:.3f}', _is_best(p, best_p, 3))} / "
                f"{_bold_if(f'{a:.3f}', _is_best(a, best_a, 3))}"
            )
        s = speed[tracker]
        cells.append("" if s is None else _bold_if(f"{s:.1f}", _is_best(s, best_speed, 1)))
        body.append(cells)
    header = ["Tracker", *(f"{_cell(ds)} P@20 / AUC" for ds in datasets), "Mean P@20 / AUC", "FPS"]
    table = _markdown(header, body)
    if note:
        conv = conventions.pop() if conventions else "unknown"
        table += (
            f"\nP@20: precision at 20 px; AUC: area under the success plot; {conv} convention; "
            "best per column in bold.\n"
        )
    return table


def _finite(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(float(v)) else float(v)


# --------------------------------------------------------------------------- Table 2


def read_map_difference(path: str | os.PathLike[str]) -> np.ndarray:
    """One sequence's per-frame response-map differences (whitespace/comma separated, NaN ok)."""
    text = Path(path).read_text(encoding="utf-8").replace(",", " ")
    try:
        return np.array([float(tok) for tok in text.split()], dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"{path}: not a list of numbers ({exc})") from None


def map_difference_files(results_dir: str | os.PathLike[str]) -> list[Path]:
    """The ``<sequence>_map_diff.txt`` files of a result folder, sorted by name."""
    folder = Path(results_dir)
    if not folder.is_dir():
        raise FileNotFoundError(f"results folder not found: {folder}")
    return sorted(p for p in folder.glob(f"*{MAP_DIFF_SUFFIX}") if p.is_file())


def map_difference_mean(
    files: Iterable[str | os.PathLike[str]], average: MapDiffAverage = "pooled"
) -> float:
    """Average response-map difference over sequences, as in the paper's Table 2.

    Frame 1 of every file is skipped (there is no previous response map, so its 0 is not a
    measurement) and NaN frames are ignored. ``average``:

    ``"pooled"`` (default)
        Mean over all remaining frames of all sequences together. This reproduces the paper:
        0.0106 (ARCF-H) and 0.0133 (BACF) on UAV123@10fps (measured 0.010596 / 0.013325).
    ``"per_sequence"``
        Mean over sequences of each sequence's mean; every sequence weighs the same. It gives
        0.0109 / 0.0139 (0.010892 / 0.013898) on the same files, not the paper's figures.

    A sequence with no usable frame adds nothing; no usable frame at all is a ``ValueError``.
    """
    if average not in ("pooled", "per_sequence"):
        raise ValueError(f"unknown average {average!r}; expected 'pooled' or 'per_sequence'")
    total, count, seq_means = 0.0, 0, []
    paths = list(files)
    for path in paths:
        values = read_map_difference(path)[1:]
        values = values[~np.isnan(values)]
        if values.size == 0:
            continue
        total += float(values.sum())
        count += values.size
        seq_means.append(float(values.mean()))
    if count == 0:
        raise ValueError(f"no map-difference values after the first frame in {len(paths)} files")
    return total / count if average == "pooled" else float(np.mean(seq_means))


def table2_markdown(values: Mapping[str, Mapping[str, float]]) -> str:
    """Markdown version of Table 2: tracker -> dataset -> average map difference, 4 decimals.

    Lower is better (a smaller change of the response map between frames means fewer
    aberrances), so the lowest value per column is bold; a missing value shows "—".
    """
    if not values:
        raise ValueError("no values for the table")
    datasets = _datasets(values)
    body = []
    for tracker, per in values.items():
        cells = [_cell(tracker)]
        for ds in datasets:
            best = _best((_finite(v.get(ds)) for v in values.values()), 4, higher=False)
            v = _finite(per.get(ds))
            cells.append("—" if v is None else _bold_if(f"{v:.4f}", _is_best(v, best, 4)))
        body.append(cells)
    return _markdown(["Tracker", *(_cell(ds) for ds in datasets)], body)


# --------------------------------------------------------------------------- aberrance figure


def plot_map_difference(
    series: Mapping[str, np.ndarray],
    path: str | os.PathLike[str],
    title: str = "",
    *,
    ours: Collection[str] = frozenset(),
    dpi: int = _DPI,
) -> Path:
    """Per-frame response-map difference of several trackers on one sequence.

    Like the paper's aberrance figure: x = frame number (1-based; drawn from frame 2, as frame 1
    has no previous map), y = the difference between consecutive response maps. Spikes are
    aberrances; a repressed tracker's curve stays lower and flatter. The legend shows each
    tracker's mean over frames 2..n (NaN ignored). Series may differ in length. Returns the PNG
    path.
    """
    if not series:
        raise ValueError("no series to plot")
    styles = _style(series)
    fig = _new_figure(7.0, 3.2)
    ax = fig.add_subplot()
    top = 0.0
    for name, values in series.items():
        y = np.asarray(values, dtype=np.float64).ravel()
        rest = y[1:][~np.isnan(y[1:])]
        # Frame 1 has no previous map: its 0 is a placeholder, drawn it would fake a dip.
        mean = f"{rest.mean():.4f}" if rest.size else "n/a"
        colour, linestyle = styles[name]
        mine = name in ours
        ax.plot(
            np.arange(2, y.size + 1),
            y[1:],
            color=colour,
            linestyle="-" if mine else linestyle,
            linewidth=1.6 if mine else 1.0,
            zorder=3 if mine else 2,
            label=f"{name} [mean {mean}]",
        )
        if rest.size:
            top = max(top, float(np.max(rest)))
    ax.set_xlabel("Frame number")
    ax.set_ylabel("Response map difference")
    ax.set_xlim(left=1)  # frame axis starts where the sequence does
    ax.set_ylim(0.0, top * 1.05 if top > 0 else 1.0)
    if title:
        ax.set_title(title)
    ax.grid(True, linestyle=":", linewidth=0.6, alpha=0.7)
    ax.legend(loc="upper right", fontsize="small", framealpha=0.85)
    fig.tight_layout()
    return _save(fig, path, dpi)

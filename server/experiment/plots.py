"""The report's figures, as PNG bytes: per-observer psychometric curves like the paper's Fig. 13
and PSE distributions like Fig. 14 (matplotlib, Agg: no display needed)."""

from __future__ import annotations

import io
import math
from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection

from gazehdr.experiment import psychometric as pm
from gazehdr.experiment.analysis import FITTED, ConditionFit, ObserverResult, TaskResult

CONTROL = "#1f5fbf"  # blue, as the paper's control
AFTERIMAGE = "#2a9d3a"  # green: Fig. 13's afterimage (4.1) manipulated curves
MESOPIC = "#d0312d"  # red: Fig. 13's mesopic (4.2) manipulated curves


def colours(task: str) -> dict[str, str]:
    """Control blue; manipulated red for a mesopic task (by its name), else green."""
    return {"control": CONTROL, "manipulated": MESOPIC if "mesopic" in task.lower() else AFTERIMAGE}


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def _x_range(fits: Sequence[ConditionFit]) -> tuple[float, float]:
    xs = [x for f in fits for x in f.levels.x]
    xs += [f.fit.pse for f in fits if f.fit.pse is not None]
    lo, hi = (min(xs), max(xs)) if xs else (-0.3, 0.3)
    pad = 0.1 * (hi - lo) if hi > lo else 0.1
    return lo - pad, hi + pad


def draw_observer(ax, result: ObserverResult, palette: dict[str, str], title: str) -> None:
    """Proportions "test brighter" per level, fitted curves, dashed PSE lines (Fig. 13)."""
    fits = list(result.fits.values())
    lo, hi = _x_range(fits)
    grid = np.linspace(lo, hi, 200)
    for f in fits:
        colour = palette.get(f.condition, "grey")
        lv = f.levels
        if len(lv.x):
            ax.scatter(lv.x, lv.k / lv.n, s=12 + 2 * lv.n, color=colour, alpha=0.8, zorder=3)
        fit = f.fit
        if fit.pse is not None and fit.sigma is not None and fit.lapse is not None:
            ax.plot(grid, pm.psychometric(grid, fit.pse, fit.sigma, fit.lapse), color=colour)
            ax.axvline(fit.pse, color=colour, linestyle="--", linewidth=1)
        elif fit.flag in pm.UNBOUNDED:
            edge, mark = (lo, "<") if fit.flag == "below_range" else (hi, ">")
            ax.plot([edge], [0.5], marker=mark, color=colour, markersize=9, clip_on=False)
    ax.axhline(0.5, color="0.8", linewidth=0.8, zorder=0)
    ax.set_xlim(lo, hi)
    ax.set_ylim(-0.03, 1.03)
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)


def _legend(fig, palette: dict[str, str]) -> None:
    handles = [plt.Line2D([], [], color=c, marker="o", label=k) for k, c in palette.items()]
    fig.legend(
        handles=handles,
        loc="lower center",
        bbox_to_anchor=(0.5, 1.0),
        ncol=len(handles),
        fontsize=8,
        frameon=False,
    )


def figure13(task: TaskResult, picks: Sequence[tuple[str, ObserverResult]]) -> bytes:
    """The representative observers side by side, as one row of Fig. 13."""
    palette = colours(task.task)
    fig, axes = plt.subplots(1, len(picks), figsize=(3.2 * len(picks), 2.8), squeeze=False)
    for ax, (label, result) in zip(axes[0], picks, strict=True):
        draw_observer(ax, result, palette, f"{result.observer.participant}: {label}")
        ax.set_xlabel("log10 relative intensity", fontsize=8)
    axes[0][0].set_ylabel('P("test brighter")', fontsize=8)
    _legend(fig, palette)
    return _png(fig)


def observer_grid(task: TaskResult, columns: int = 4) -> bytes:
    """Every included observer, the same way."""
    shown = task.included
    rows = max(1, math.ceil(len(shown) / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(2.6 * columns, 2.2 * rows), squeeze=False)
    palette = colours(task.task)
    for i, ax in enumerate(axes.flat):
        if i < len(shown):
            draw_observer(ax, shown[i], palette, shown[i].observer.participant)
        else:
            ax.axis("off")
    fig.supxlabel("log10 relative intensity", fontsize=9)
    fig.supylabel('P("test brighter")', fontsize=9)
    fig.tight_layout()
    _legend(fig, palette)
    return _png(fig)


def figure14(task: TaskResult) -> bytes:
    """Fig. 14 as PNG bytes (`draw_figure14`)."""
    return _png(draw_figure14(task))


def interval_gid(condition: str) -> str:
    """The gid of the LineCollection that draws a condition's PSE intervals in Fig. 14."""
    return f"pse-intervals-{condition}"


def draw_figure14(task: TaskResult):
    """PSEs per condition, one dot per observer with its bootstrap interval as an error bar,
    the median as a box (Fig. 14). An unbounded PSE is an arrowhead at the axis' end; an
    interval end that reaches the PSE search bound (`ConditionFit.ci_open`: the data cannot
    close it) ends in an arrowhead instead of a cap. Each condition's intervals are one
    LineCollection (gid `interval_gid(condition)`), a segment per observer in the order of
    its dots. The analysis gives the median no interval, so none is drawn."""
    palette = colours(task.task)
    fig, ax = plt.subplots(figsize=(6.4, 2.2))
    values = []
    for row, condition in enumerate(FITTED):
        fits = [o.fits[condition] for o in task.included if condition in o.fits]
        usable = [f for f in fits if f.fit.usable and f.fit.rank_value is not None]
        y = len(FITTED) - 1 - row
        jitter = np.linspace(-0.12, 0.12, len(usable)) if len(usable) > 1 else np.zeros(len(usable))
        segments = []
        for f, dy in zip(usable, jitter, strict=True):
            fit = f.fit
            assert fit.rank_value is not None
            mark = {"below_range": "<", "above_range": ">"}.get(fit.flag, "o")
            ax.plot(fit.rank_value, y + dy, marker=mark, color=palette[condition], alpha=0.8)
            values.append(fit.rank_value)
            if f.ci is not None:
                (lo, hi), opened = f.ci, f.ci_open
                segments.append([(lo, y + dy), (hi, y + dy)])
                for end, is_open, arrow in ((lo, opened[0], "<"), (hi, opened[1], ">")):
                    ax.plot(end, y + dy, marker=arrow if is_open else "|", markersize=5,
                            color=palette[condition], alpha=0.6)  # fmt: skip
                values += [lo, hi]
        if segments:
            lines = LineCollection(
                segments, colors=palette[condition], linewidths=1.2, alpha=0.6, zorder=1
            )
            lines.set_gid(interval_gid(condition))
            ax.add_collection(lines)
        median = (
            task.group.median_control if condition == "control" else task.group.median_manipulated
        )
        if median is not None:
            ax.plot(median, y, marker="s", markersize=14, markerfacecolor="none", color="black")
    ax.axvline(0.0, color="0.8", linewidth=0.8, zorder=0)
    ax.set_yticks([1, 0], ["control", "manipulated"])
    ax.set_ylim(-0.6, 1.6)
    if values:
        lo, hi = min(*values, 0.0), max(*values, 0.0)
        pad = 0.08 * (hi - lo) if hi > lo else 0.1
        ax.set_xlim(lo - pad, hi + pad)
    ax.set_xlabel(
        "PSE (log10 relative intensity); bars: intervals (arrowhead: open); box: median",
        fontsize=8,
    )
    return fig

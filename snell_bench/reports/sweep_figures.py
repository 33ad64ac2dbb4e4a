"""Figures of the sweeps, drawn with matplotlib's Agg canvas and written atomically: the time-travel
curves against R_main and the Pareto plot of a speed/accuracy sweep."""

from __future__ import annotations

import os
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from .canvas import new_figure, save_png
from .text import is_missing
from .tradeoff import PRESET_AXIS, complete_front, fidelity_column

__all__ = ["time_travel_figure", "pareto_figure", "clip_outliers"]

# --------------------------------------------------------------------------------------------
# Time travel
# --------------------------------------------------------------------------------------------


def time_travel_figure(
    table: pd.DataFrame, out_png: str | os.PathLike, title: str = "", metrics: Sequence[str] = ("psnr", "lpips")
) -> Path:
    """The time-travel experiment: each metric against R_main, one line per variant.

    Args:
        table: from :func:`~snell_bench.reports.tables.time_travel_table`.
        out_png: the PNG to write.
        title: the figure's title, if any.
        metrics: one panel each; a panel without any value says why (the table's notes on it).

    Returns:
        ``out_png`` as a :class:`~pathlib.Path`.
    """
    from .spec import metric_spec

    fig = new_figure(4.2 * len(metrics), 3.4, 110)

    # the last level is R_main; the levels before it (the variant, and a swept axis where the cells
    # sweep one) name a line
    def line(k) -> str:
        return " / ".join(str(x) for x in k[:-1])

    variants = list(dict.fromkeys(line(k) for k in table.index))
    rs = sorted({int(k[-1]) for k in table.index})
    for pi, m in enumerate(metrics):
        spec = metric_spec(m)
        ax = fig.add_subplot(1, len(metrics), pi + 1)
        values = table[m] if m in table.columns else pd.Series(np.nan, index=table.index)
        drawn = False
        for vi, v in enumerate(variants):
            sel = [(int(k[-1]), float(values.iloc[i])) for i, k in enumerate(table.index) if line(k) == v]
            sel = [(r, y) for r, y in sel if np.isfinite(y)]
            if sel:
                x, y = zip(*sel)
                ax.plot(x, y, marker="os"[vi % 2], color=f"C{vi}", label=v)
                drawn = True
        ax.set_xlabel("R_main (time-travel repeats of the main view)")
        ax.set_ylabel(f"{spec.label} {spec.arrow}")
        if rs:
            ax.set_xticks(rs)
        ax.grid(True, alpha=0.3)
        if drawn:
            ax.legend(fontsize=7, loc="best")
        else:
            why = [n for n in table.attrs.get("notes", []) if n.startswith(f"{spec.label}:")]
            text = "no values" + (": " + why[0].split(" — ", 1)[-1] if why else "")
            ax.set_yticks([])
            ax.text(0.5, 0.5, textwrap.fill(text, 48), ha="center", va="center", fontsize=7, transform=ax.transAxes)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_png(fig, out_png, facecolor="white")


# --------------------------------------------------------------------------------------------
# Pareto plot
# --------------------------------------------------------------------------------------------


def pareto_figure(table: pd.DataFrame, out_png: str | os.PathLike, title: str = "") -> Path:
    """``pareto.png`` of a speed/accuracy sweep.

    Mean total seconds (log x) against mean PSNR (:func:`fidelity_column`), one marker and colour
    per axis, presets as labelled stars, the Pareto front (settings that succeeded on every scene)
    as a step line; a second panel with PSNR vs the true render when any setting has it.

    Args:
        table: per-setting means from ``tradeoff_table``.
        out_png: the PNG to write.
        title: the figure's title, if any.

    Returns:
        ``out_png`` as a :class:`~pathlib.Path`.
    """
    fid = fidelity_column(table)
    panels = [
        (
            fid,
            "mean masked PSNR vs converged reference (dB)"
            if fid == "psnr_converged"
            else "mean masked PSNR vs reference (dB)",
        )
    ]
    if table["psnr_true"].notna().any():
        panels.append(("psnr_true", "mean masked PSNR vs true render (dB)"))
    fig = new_figure(6.0 * len(panels), 4.6, 110)
    axes_names = [a for a in dict.fromkeys(table["axis"]) if a != PRESET_AXIS and not is_missing(a)]
    for pi, (metric, ylabel) in enumerate(panels):
        _pareto_panel(fig.add_subplot(1, len(panels), pi + 1), table, metric, ylabel, axes_names, legend=pi == 0)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_png(fig, out_png, facecolor="white")


def _pareto_panel(ax, table: pd.DataFrame, metric: str, ylabel: str, axes_names: list, legend: bool) -> None:
    """One panel of :func:`pareto_figure`: ``metric`` against the mean total time."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    markers = "osD^v<>phX8"
    colors = [f"C{i}" for i in range(10)]
    x = table["timings_s.total"].to_numpy(float)
    y = table[metric].to_numpy(float)
    base = table["axis"].isna().to_numpy()
    if base.any():
        ax.scatter(
            x[base], y[base], marker="o", s=60, facecolors="none", edgecolors="black", label="baseline", zorder=3
        )
    for i, a in enumerate(axes_names):
        sel = (table["axis"] == a).to_numpy()
        ax.scatter(
            x[sel], y[sel], marker=markers[i % len(markers)], color=colors[i % len(colors)], s=28, label=a, zorder=3
        )
        labels = [lab.split("=", 1)[-1] for lab in table.index[sel]]
        _annotate(ax, labels, x[sel], y[sel], fontsize=6, xytext=(3, 2), color=colors[i % len(colors)])
    pre = (table["axis"] == PRESET_AXIS).to_numpy()
    if pre.any():
        ax.scatter(
            x[pre],
            y[pre],
            marker="*",
            s=160,
            color="gold",
            edgecolors="black",
            linewidths=0.6,
            label="presets",
            zorder=4,
        )
        labels = [lab.split(":", 1)[-1] for lab in table.index[pre]]
        _annotate(ax, labels, x[pre], y[pre], fontsize=8, fontweight="bold", xytext=(5, -10))
    front = complete_front(table, x, y)
    if front.size:
        ax.step(x[front], y[front], where="post", color="grey", lw=1.2, ls="--", label="Pareto front", zorder=2)
        ax.scatter(x[front], y[front], s=150, facecolors="none", edgecolors="grey", linewidths=1.0, zorder=2)
    finite = x[np.isfinite(x)]
    if finite.size and (finite > 0).all():
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_minor_locator(LogLocator(base=10, subs=tuple(range(1, 10))))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(NullFormatter())
    clip_outliers(ax, table.index, x, y)
    ax.set_xlabel("mean total time per image (s, log scale)")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    if legend:
        ax.legend(fontsize=7, loc="best")


def _annotate(ax, labels, x: np.ndarray, y: np.ndarray, **kwargs) -> None:
    """Each label beside its point, offset in points (``xytext``); points off the chart get none."""
    for lab, xi, yi in zip(labels, x, y):
        if np.isfinite(xi) and np.isfinite(yi):
            ax.annotate(lab, (xi, yi), textcoords="offset points", **kwargs)


def clip_outliers(ax, labels, x: np.ndarray, y: np.ndarray) -> None:
    """Keep the y range on the bulk of the settings: settings separated from all others by a gap
    more than twice the rest of the range (e.g. one bounce, which breaks the glass) are drawn at the
    lower edge as arrows labelled with their values."""
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 4:
        return
    ys = np.sort(y[ok])
    gaps = np.diff(ys)
    i = int(np.argmax(gaps))
    if gaps[i] <= 2 * (ys[-1] - ys[i + 1]) or i + 1 > len(ys) // 2:  # no isolated low cluster
        return
    lo = ys[i + 1]
    out = ok & (y < lo)
    bottom = lo - 0.05 * (y[ok & ~out].max() - lo + 1e-9)
    ax.set_ylim(bottom=bottom)
    for lab, xi, yi in zip(np.asarray(labels)[out], x[out], y[out]):
        ax.annotate(
            f"{lab}: {yi:.2f} dB",
            (xi, bottom),
            xytext=(0, 14),
            textcoords="offset points",
            fontsize=6,
            ha="center",
            arrowprops={"arrowstyle": "->", "lw": 0.8, "color": "black"},
        )

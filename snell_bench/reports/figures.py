"""Figures, drawn with matplotlib's Agg canvas and written atomically: a grid's qualitative pages,
the main image beside its panorama (the paper's Fig. 4), time-travel curves and the Pareto plot."""

from __future__ import annotations

import math
import os
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from snell_bench.utils.io import atomic_write

from .collect import collect
from .tables import method_labels, object_ior
from .text import is_missing
from .tradeoff import PRESET_AXIS, complete_front, fidelity_column

__all__ = [
    "figure_rows",
    "pages",
    "qualitative_figure",
    "qualitative_pages",
    "panorama_rows",
    "panorama_figure",
    "panorama_pages",
    "time_travel_figure",
    "pareto_figure",
]


def _save(fig, out_png: str | os.PathLike, **kwargs) -> Path:
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out_png, lambda f: fig.savefig(f, format="png", metadata={"Software": None}, **kwargs))
    return out_png


# --------------------------------------------------------------------------------------------
# Qualitative comparison
# --------------------------------------------------------------------------------------------


def _load_rgb(path: Path) -> np.ndarray | None:
    from PIL import Image

    if not path.is_file():
        return None
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    except OSError:
        return None


def _mask_box(path: Path) -> tuple[float, float, float, float] | None:
    """Bounding box of the white pixels of a mask as fractions (x0, y0, x1, y1) of its size."""
    img = _load_rgb(path)
    if img is None:
        return None
    m = img.mean(-1) > 0.5
    if not m.any():
        return None
    ys, xs = np.nonzero(m)
    H, W = m.shape
    return xs.min() / W, ys.min() / H, (xs.max() + 1) / W, (ys.max() + 1) / H


def _zoom_window(box, W: int, H: int, pad: float = 0.15) -> tuple[int, int, int, int]:
    """A square pixel window around a fractional box, padded and kept inside the image."""
    x0, y0, x1, y1 = box[0] * W, box[1] * H, box[2] * W, box[3] * H
    side = max(x1 - x0, y1 - y0) * (1 + 2 * pad)
    side = int(min(max(side, 8), W, H))
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    left = int(round(min(max(cx - side / 2, 0), W - side)))
    top = int(round(min(max(cy - side / 2, 0), H - side)))
    return left, top, left + side, top + side


def _object_label(obj: str) -> str:
    name, ior = object_ior(obj)
    return str(obj) if math.isnan(ior) else f"{name}, IOR {ior:g}"


def _row_label(scene: str, variation: int, obj: str) -> str:
    """A row's label on two lines: ``"kitchen-0\\nsphere, IOR 1.333"``."""
    return f"{scene}-{variation}\n{_object_label(obj)}"


def _cell_label(cell_dir: str) -> str:
    """A cell folder ``<scene>-<variation>/<object>/<method>`` as two lines."""
    parts = cell_dir.split("/")
    if len(parts) < 3:
        return cell_dir
    return f"{parts[-3]} / {_object_label(parts[-2])}\n{parts[-1]}"


def figure_rows(df: pd.DataFrame, by_ior: bool = False) -> list[tuple[str, int, str]]:
    """Every ``(scene, variation, object)`` of the cells, in figure order.

    Args:
        df: cells from ``collect``.
        by_ior: order by object name, then IOR, then scene and variation (the IOR sweep), instead
            of the first cell of each scene (by variation, then object) followed by the others.

    Returns:
        The rows, each once.
    """
    df = df.dropna(subset=["scene", "variation", "object"])
    keys = sorted({(str(r.scene), int(r.variation), str(r.object)) for r in df.itertuples()})
    if by_ior:

        def key(k):
            name, ior = object_ior(k[2])
            return (name, 0 if math.isnan(ior) else 1, 0.0 if math.isnan(ior) else ior, k[0], k[1])

        return sorted(keys, key=key)
    chosen, scenes = [], set()
    for k in keys:
        if k[0] not in scenes:
            chosen.append(k)
            scenes.add(k[0])
    return chosen + [k for k in keys if k not in chosen]


def pages(rows: Sequence, max_rows: int) -> list[list]:
    """``rows`` cut into pages of at most ``max_rows``, in order: ``ceil(len(rows) / max_rows)``
    pages (none for no rows) holding every row once.

    Raises:
        ValueError: ``max_rows`` is below 1.
    """
    if int(max_rows) < 1:
        raise ValueError(f"max_rows must be >= 1, got {max_rows}")
    rows = list(rows)
    return [rows[i : i + int(max_rows)] for i in range(0, len(rows), int(max_rows))]


def _cells_of(run_dir: Path, df: pd.DataFrame | None) -> pd.DataFrame:
    """``df`` (the cells a caller already collected), else :func:`collect` of ``run_dir``; raises
    ``FileNotFoundError`` when there is no cell."""
    if df is None:
        df = collect(run_dir)
    if df.empty:
        raise FileNotFoundError(f"no cells (metrics.json) below {run_dir}")
    return df


def qualitative_pages(
    run_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    stem: str = "qualitative",
    *,
    max_rows: int = 4,
    cells: Sequence[tuple[str, int, str]] | None = None,
    methods: Sequence[str] | None = None,
    df: pd.DataFrame | None = None,
    **kwargs,
) -> list[Path]:
    """The qualitative comparison of every row, one PNG per ``max_rows`` rows.

    Args:
        run_dir: the experiment's run directory.
        out_dir: where to write ``<stem>_1.png``, ``<stem>_2.png``, ...
        stem: the file names' stem.
        max_rows: rows per page.
        cells: the rows; default every ``(scene, variation, object)`` (:func:`figure_rows`).
        methods: the columns after the reference, as in :func:`qualitative_figure`.
        df: the cells of ``run_dir`` when the caller has them (:func:`collect`); else collected here.
        **kwargs: passed to :func:`qualitative_figure` (``inset``, ``tile_width_in``, ``dpi``).

    Returns:
        The pages written, ``ceil(rows / max_rows)`` of them.

    Raises:
        FileNotFoundError: there is no cell below ``run_dir``.
    """
    run_dir, out_dir = Path(run_dir), Path(out_dir)
    df = _cells_of(run_dir, df)
    if cells is None:
        cells = figure_rows(df)
    return [
        qualitative_figure(run_dir, out_dir / f"{stem}_{k}.png", cells=page, methods=methods, df=df, **kwargs)
        for k, page in enumerate(pages(cells, max_rows), start=1)
    ]


def qualitative_figure(
    run_dir: str | os.PathLike,
    out_png: str | os.PathLike,
    cells: Sequence[tuple[str, int, str]] | None = None,
    methods: Sequence[str] | None = None,
    inset: bool = True,
    *,
    max_rows: int | None = 4,
    tile_width_in: float = 2.4,
    dpi: int = 100,
    df: pd.DataFrame | None = None,
) -> Path:
    """A grid PNG: one row per cell ``(scene, variation, object)``, columns reference |
    Snellcaster | the other methods, each tile with an inset zoom on the object.

    The reference is the row's ``reference.png`` (from the Snellcaster cell when it has one). The
    inset crops a square around the bounding box of the row's ``mask.png`` (the same window in
    every tile of the row, marked by a yellow frame) and sits in the tile's corner farthest from
    the object; a tile without an image says why. Tiles keep the aspect ratio of the first image
    found.

    Args:
        run_dir: the experiment's run directory.
        out_png: the PNG to write.
        cells: the rows; default the first cell (by variation, then object) of each scene, then
            further cells (:func:`figure_rows`), up to ``max_rows``; :func:`qualitative_pages`
            draws every row on as many pages as needed.
        methods: the columns after the reference; default ``snellcaster`` followed by the other
            methods, sorted.
        inset: draw the zoom insets.
        max_rows: the most rows when ``cells`` is not given (None: every row).
        tile_width_in: the width of a tile in inches.
        dpi: pixels per inch; the figure is ``dpi * (0.3 + tile_width_in * n_columns)`` pixels wide.
        df: the cells of ``run_dir`` when the caller has them (:func:`collect`); else collected here.

    Returns:
        ``out_png`` as a :class:`~pathlib.Path`.

    Raises:
        FileNotFoundError: there is no cell below ``run_dir``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    run_dir = Path(run_dir)
    df = _cells_of(run_dir, df).dropna(subset=["scene", "variation", "object", "method"])
    if cells is None:
        cells = figure_rows(df)
        cells = cells if max_rows is None else cells[:max_rows]
    cells = [(str(s), int(v), str(o)) for s, v, o in cells]
    all_methods = sorted(df["method"].astype(str).unique())
    if methods is None:
        methods = (["snellcaster"] if "snellcaster" in all_methods else []) + [
            m for m in all_methods if m != "snellcaster"
        ]
    methods = list(methods)
    labels = method_labels(df)

    def cell_row(key, method):
        g = df[
            (df["scene"] == key[0]) & (df["variation"] == key[1]) & (df["object"] == key[2]) & (df["method"] == method)
        ]
        return None if g.empty else g.iloc[0]

    # one (image, reason) per tile; the reference and the mask per row
    grid, boxes = [], []
    for key in cells:
        rows = {m: cell_row(key, m) for m in methods}
        same_row = df[(df["scene"] == key[0]) & (df["variation"] == key[1]) & (df["object"] == key[2])]
        dirs = [run_dir / r["cell_dir"] for r in rows.values() if r is not None] + [
            run_dir / d for d in same_row["cell_dir"]
        ]
        ref = next((img for d in dirs if (img := _load_rgb(d / "reference.png")) is not None), None)
        box = next((b for d in dirs if (b := _mask_box(d / "mask.png")) is not None), None)
        tiles = [(ref, "no reference.png")]
        for m in methods:
            r = rows[m]
            if r is None:
                tiles.append((None, "not run"))
                continue
            img = _load_rgb(run_dir / r["cell_dir"] / "image.png")
            why = r["status"] if r["status"] != "ok" else "no image.png"
            if r["status"] != "ok" and isinstance(r.get("reason"), str):
                why += ": " + r["reason"]
            tiles.append((img, why))
        grid.append(tiles)
        boxes.append(box)

    first = next((img for tiles in grid for img, _ in tiles if img is not None), None)
    aspect = first.shape[0] / first.shape[1] if first is not None else 9 / 16
    ncols, nrows = 1 + len(methods), max(len(cells), 1)
    left_in, top_in = 0.3, 0.3
    tile_h_in = tile_width_in * aspect
    fig_w, fig_h = left_in + ncols * tile_width_in, top_in + nrows * tile_h_in
    fig = Figure(figsize=(fig_w, fig_h), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    titles = ["Reference"] + [labels.get(m, m) for m in methods]
    gap = 0.03  # fraction of a tile left blank on each side
    for i, tiles in enumerate(grid):
        for j, (img, why) in enumerate(tiles):
            x = (left_in + j * tile_width_in) / fig_w
            y = 1 - (top_in + (i + 1) * tile_h_in) / fig_h
            w, h = tile_width_in / fig_w, tile_h_in / fig_h
            ax = fig.add_axes((x + gap * w, y + gap * h, w * (1 - 2 * gap), h * (1 - 2 * gap)))
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(titles[j], fontsize=9, pad=3)
            if img is None:
                ax.set_facecolor((0.85, 0.85, 0.85))
                text = why if len(why) <= 60 else why[:57] + "..."
                ax.text(0.5, 0.5, text, ha="center", va="center", fontsize=6, wrap=True, transform=ax.transAxes)
                continue
            ax.imshow(img, interpolation="antialiased")
            ax.set_aspect("auto")
            box = boxes[i]
            if inset and box is not None:
                H, W = img.shape[:2]
                x0, y0, x1, y1 = _zoom_window(box, W, H)
                ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, ec="yellow", lw=0.8))
                side_in = 0.42 * min(tile_width_in, tile_h_in)
                iw, ih = side_in / tile_width_in, side_in / tile_h_in
                # the corner farthest from the object, so the inset hides as little of it as possible
                cx, cy = (x0 + x1) / 2 / W, (y0 + y1) / 2 / H
                ix = 1 - iw - 0.01 if cx < 0.5 else 0.01
                iy = 0.01 if cy < 0.5 else 1 - ih - 0.01
                sub = ax.inset_axes((ix, iy, iw, ih))
                sub.imshow(img[y0:y1, x0:x1], interpolation="nearest")
                sub.set_aspect("auto")
                sub.set_xticks([])
                sub.set_yticks([])
                for sp in sub.spines.values():
                    sp.set_edgecolor("yellow")
                    sp.set_linewidth(1.0)
        key = cells[i]
        fig.text(
            0.5 * left_in / fig_w,
            1 - (top_in + (i + 0.5) * tile_h_in) / fig_h,
            _row_label(*key),
            rotation=90,
            ha="center",
            va="center",
            fontsize=7,
        )
    return _save(fig, out_png, dpi=dpi, facecolor="white")


# --------------------------------------------------------------------------------------------
# Main image and panorama (Fig. 4)
# --------------------------------------------------------------------------------------------

PANORAMA_FILE = "panorama.png"
"""The panorama branch's image in a Snellcaster cell's folder."""


def panorama_rows(df: pd.DataFrame, run_dir: str | os.PathLike) -> list[str]:
    """The cell folders (relative to ``run_dir``) with status ``ok`` and a ``panorama.png``, in
    the order of ``collect`` (scene, variation, object, method)."""
    run_dir = Path(run_dir)
    ok = df[df["status"] == "ok"]
    return [d for d in ok["cell_dir"] if (run_dir / d / PANORAMA_FILE).is_file()]


def panorama_figure(
    run_dir: str | os.PathLike,
    out_png: str | os.PathLike,
    cell_dirs: Sequence[str],
    *,
    tile_width_in: float = 2.4,
    dpi: int = 100,
) -> Path:
    """One row per cell: its main image beside its panorama, at the same height (the paper's Fig. 4).

    Args:
        run_dir: the experiment's run directory.
        out_png: the PNG to write.
        cell_dirs: the rows: cell folders relative to ``run_dir`` (:func:`panorama_rows`).
        tile_width_in: the width of the main image's tile in inches; the panorama's tile has the
            same height and the panorama's aspect ratio.
        dpi: pixels per inch.

    Returns:
        ``out_png`` as a :class:`~pathlib.Path`.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    run_dir = Path(run_dir)
    rows = [(d, _load_rgb(run_dir / d / "image.png"), _load_rgb(run_dir / d / PANORAMA_FILE)) for d in cell_dirs]
    img0 = next((im for _, im, _ in rows if im is not None), None)
    pano0 = next((p for _, _, p in rows if p is not None), None)
    aspect = img0.shape[0] / img0.shape[1] if img0 is not None else 9 / 16
    pano_aspect = pano0.shape[1] / pano0.shape[0] if pano0 is not None else 2.0
    left_in, top_in = 0.3, 0.3
    tile_h_in = tile_width_in * aspect
    pano_w_in = tile_h_in * pano_aspect
    fig_w, fig_h = left_in + tile_width_in + pano_w_in, top_in + max(len(rows), 1) * tile_h_in
    fig = Figure(figsize=(fig_w, fig_h), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    gap = 0.03
    for i, (d, img, pano) in enumerate(rows):
        y = 1 - (top_in + (i + 1) * tile_h_in) / fig_h
        h = tile_h_in / fig_h
        for x0_in, w_in, im, title, missing in (
            (left_in, tile_width_in, img, "Image", "no image.png"),
            (left_in + tile_width_in, pano_w_in, pano, "Panorama", f"no {PANORAMA_FILE}"),
        ):
            x, w = x0_in / fig_w, w_in / fig_w
            ax = fig.add_axes(
                (x + gap * tile_width_in / fig_w, y + gap * h, w - 2 * gap * tile_width_in / fig_w, h * (1 - 2 * gap))
            )
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(title, fontsize=9, pad=3)
            if im is None:
                ax.set_facecolor((0.85, 0.85, 0.85))
                ax.text(0.5, 0.5, missing, ha="center", va="center", fontsize=6, transform=ax.transAxes)
                continue
            ax.imshow(im, interpolation="antialiased")
            ax.set_aspect("auto")
        fig.text(
            0.5 * left_in / fig_w,
            1 - (top_in + (i + 0.5) * tile_h_in) / fig_h,
            _cell_label(str(d)),
            rotation=90,
            ha="center",
            va="center",
            fontsize=6,
        )
    return _save(fig, out_png, dpi=dpi, facecolor="white")


def panorama_pages(
    run_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    stem: str = "panorama",
    *,
    max_rows: int = 4,
    df: pd.DataFrame | None = None,
    **kwargs,
) -> list[Path]:
    """:func:`panorama_figure` of every cell with a panorama, one PNG per ``max_rows`` rows
    (``<stem>_1.png``, ...); none when no cell has one.

    Raises:
        FileNotFoundError: there is no cell below ``run_dir``.
    """
    run_dir, out_dir = Path(run_dir), Path(out_dir)
    df = _cells_of(run_dir, df)
    return [
        panorama_figure(run_dir, out_dir / f"{stem}_{k}.png", page, **kwargs)
        for k, page in enumerate(pages(panorama_rows(df, run_dir), max_rows), start=1)
    ]


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
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from .spec import metric_spec

    fig = Figure(figsize=(4.2 * len(metrics), 3.4), dpi=110, facecolor="white")
    FigureCanvasAgg(fig)

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
    return _save(fig, out_png, facecolor="white")


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
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

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
    fig = Figure(figsize=(6.0 * len(panels), 4.6), dpi=110, facecolor="white")
    FigureCanvasAgg(fig)
    axes_names = [a for a in dict.fromkeys(table["axis"]) if a != PRESET_AXIS and not is_missing(a)]
    for pi, (metric, ylabel) in enumerate(panels):
        _pareto_panel(fig.add_subplot(1, len(panels), pi + 1), table, metric, ylabel, axes_names, legend=pi == 0)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, out_png, facecolor="white")


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
        for lab, xi, yi in zip(table.index[sel], x[sel], y[sel]):
            if np.isfinite(xi) and np.isfinite(yi):
                ax.annotate(
                    lab.split("=", 1)[-1],
                    (xi, yi),
                    fontsize=6,
                    xytext=(3, 2),
                    textcoords="offset points",
                    color=colors[i % len(colors)],
                )
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
        for lab, xi, yi in zip(table.index[pre], x[pre], y[pre]):
            if np.isfinite(xi) and np.isfinite(yi):
                ax.annotate(
                    lab.split(":", 1)[-1],
                    (xi, yi),
                    fontsize=8,
                    fontweight="bold",
                    xytext=(5, -10),
                    textcoords="offset points",
                )
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

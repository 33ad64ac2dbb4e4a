"""Figures of a grid, drawn with matplotlib's Agg canvas and written atomically: the qualitative
pages and the main image beside its panorama (the paper's Fig. 4). The sweeps' figures (time travel,
the Pareto plot) are :mod:`~snell_bench.reports.sweep_figures`, re-exported here."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from .canvas import load_rgb, new_figure, save_png
from .collect import collect
from .sweep_figures import clip_outliers, pareto_figure, time_travel_figure
from .swept import object_ior, object_order
from .tables import method_labels

__all__ = [
    "figure_rows",
    "method_columns",
    "pages",
    "qualitative_figure",
    "qualitative_pages",
    "panorama_rows",
    "panorama_figure",
    "panorama_pages",
    "time_travel_figure",
    "pareto_figure",
    "clip_outliers",
]


# --------------------------------------------------------------------------------------------
# Qualitative comparison
# --------------------------------------------------------------------------------------------


def _mask_box(path: Path, root: Path) -> tuple[float, float, float, float] | None:
    """Bounding box of the white pixels of a mask as fractions (x0, y0, x1, y1) of its size."""
    img = load_rgb(path, root)
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
    return str(obj) if ior != ior else f"{name}, IOR {ior:g}"


def _row_label(scene: str, variation: int, obj: str) -> str:
    """A row's label on two lines: ``"kitchen-0\\nsphere, IOR 1.333"``."""
    return f"{scene}-{variation}\n{_object_label(obj)}"


def _cell_label(cell_dir: str) -> str:
    """A cell folder ``<scene>-<variation>/<object>/<method>`` as two lines."""
    parts = cell_dir.split("/")
    if len(parts) < 3:
        return cell_dir
    return f"{parts[-3]} / {_object_label(parts[-2])}\n{parts[-1]}"


def method_columns(df: pd.DataFrame) -> list[str]:
    """The methods of the cells as a figure's columns: ``snellcaster`` first, the others sorted; of
    a grid with settings (``<method>@<setting>``, ``grid.axes``) the baseline and the presets
    only (every setting is in the page's gallery and the speed/accuracy report).

    Examples:
        >>> method_columns(pd.DataFrame({"method": ["t2i", "snellcaster", "no_pano"]}))
        ['snellcaster', 'no_pano', 't2i']
        >>> method_columns(pd.DataFrame({"method": ["snellcaster@steps=4", "snellcaster@preset-fast", "snellcaster@baseline"]}))
        ['snellcaster@baseline', 'snellcaster@preset-fast']
    """
    names = sorted(df["method"].astype(str).unique())
    if any("@" in n for n in names):
        names = [
            n for n in names if n.partition("@")[2] in ("", "baseline") or n.partition("@")[2].startswith("preset-")
        ]
    first = [n for n in ("snellcaster", "snellcaster@baseline") if n in names]
    return first + [m for m in names if m not in first]


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
        return sorted(keys, key=lambda k: object_order(k[2]) + (k[0], k[1]))
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
    run_dir = Path(run_dir)
    df = _cells_of(run_dir, df).dropna(subset=["scene", "variation", "object", "method"])
    if cells is None:
        cells = figure_rows(df)
        cells = cells if max_rows is None else cells[:max_rows]
    cells = [(str(s), int(v), str(o)) for s, v, o in cells]
    methods = method_columns(df) if methods is None else list(methods)
    labels = method_labels(df)
    rows = [_row_tiles(df, run_dir, key, methods) for key in cells]
    first = next((img for tiles, _ in rows for img, _ in tiles if img is not None), None)
    aspect = first.shape[0] / first.shape[1] if first is not None else 9 / 16
    ncols, nrows = 1 + len(methods), max(len(cells), 1)
    left_in, top_in = 0.3, 0.3
    tile_h_in = tile_width_in * aspect
    fig_w, fig_h = left_in + ncols * tile_width_in, top_in + nrows * tile_h_in
    fig = new_figure(fig_w, fig_h, dpi)
    titles = ["Reference"] + [labels.get(m, m) for m in methods]
    gap = 0.03  # fraction of a tile left blank on each side
    for i, (tiles, box) in enumerate(rows):
        for j, (img, why) in enumerate(tiles):
            x = (left_in + j * tile_width_in) / fig_w
            y = 1 - (top_in + (i + 1) * tile_h_in) / fig_h
            w, h = tile_width_in / fig_w, tile_h_in / fig_h
            rect = (x + gap * w, y + gap * h, w * (1 - 2 * gap), h * (1 - 2 * gap))
            ax = _tile(fig, rect, img, titles[j] if i == 0 else None, why, wrap=True)
            if ax is not None and inset and box is not None:
                _inset(ax, img, box, tile_width_in, tile_h_in)
        y = 1 - (top_in + (i + 0.5) * tile_h_in) / fig_h
        _row_text(fig, 0.5 * left_in / fig_w, y, _row_label(*cells[i]), 7)
    return save_png(fig, out_png, dpi=dpi, facecolor="white")


def _row_tiles(
    df: pd.DataFrame, run_dir: Path, key: tuple[str, int, str], methods: Sequence[str]
) -> tuple[list[tuple[np.ndarray | None, str]], tuple | None]:
    """One row of :func:`qualitative_figure`: per column, the image and why there is none (the
    reference first, then each method's), and the box of the row's mask (None without one)."""
    same_row = df[(df["scene"] == key[0]) & (df["variation"] == key[1]) & (df["object"] == key[2])]
    cells = {m: same_row[same_row["method"] == m] for m in methods}
    rows = {m: None if g.empty else g.iloc[0] for m, g in cells.items()}
    dirs = [run_dir / r["cell_dir"] for r in rows.values() if r is not None] + [
        run_dir / d for d in same_row["cell_dir"]
    ]
    ref = next((img for d in dirs if (img := load_rgb(d / "reference.png", run_dir)) is not None), None)
    box = next((b for d in dirs if (b := _mask_box(d / "mask.png", run_dir)) is not None), None)
    tiles = [(ref, "no reference.png")]
    for m in methods:
        r = rows[m]
        if r is None:
            tiles.append((None, "not run"))
            continue
        why = r["status"] if r["status"] != "ok" else "no image.png"
        if r["status"] != "ok" and isinstance(r.get("reason"), str):
            why += ": " + r["reason"]
        tiles.append((load_rgb(run_dir / r["cell_dir"] / "image.png", run_dir), why))
    return tiles, box


def _tile(fig, rect, img: np.ndarray | None, title: str | None, missing: str, wrap: bool = False):
    """One tile of a figure's grid at ``rect`` (figure fractions): ``img``, or a gray tile saying
    ``missing`` (cut at 60 characters); ``title`` above it. Returns the axes holding the image,
    None for a gray tile."""
    ax = fig.add_axes(rect)
    ax.set_xticks([])
    ax.set_yticks([])
    if title is not None:
        ax.set_title(title, fontsize=9, pad=3)
    if img is None:
        ax.set_facecolor((0.85, 0.85, 0.85))
        text = missing if len(missing) <= 60 else missing[:57] + "..."
        ax.text(0.5, 0.5, text, ha="center", va="center", fontsize=6, wrap=wrap, transform=ax.transAxes)
        return None
    ax.imshow(img, interpolation="antialiased")
    ax.set_aspect("auto")
    return ax


def _inset(ax, img: np.ndarray, box, tile_w_in: float, tile_h_in: float) -> None:
    """The zoom on ``box`` (the object) in ``ax``: a yellow frame around the window and the window
    enlarged in the tile's corner farthest from the object."""
    from matplotlib.patches import Rectangle

    H, W = img.shape[:2]
    x0, y0, x1, y1 = _zoom_window(box, W, H)
    ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, ec="yellow", lw=0.8))
    side_in = 0.42 * min(tile_w_in, tile_h_in)
    iw, ih = side_in / tile_w_in, side_in / tile_h_in
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


def _row_text(fig, x: float, y: float, text: str, fontsize: int) -> None:
    """A row's label, vertical, centred at ``(x, y)`` (figure fractions) in the left margin."""
    fig.text(x, y, text, rotation=90, ha="center", va="center", fontsize=fontsize)


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
    run_dir = Path(run_dir)
    rows = [
        (d, load_rgb(run_dir / d / "image.png", run_dir), load_rgb(run_dir / d / PANORAMA_FILE, run_dir))
        for d in cell_dirs
    ]
    img0 = next((im for _, im, _ in rows if im is not None), None)
    pano0 = next((p for _, _, p in rows if p is not None), None)
    aspect = img0.shape[0] / img0.shape[1] if img0 is not None else 9 / 16
    pano_aspect = pano0.shape[1] / pano0.shape[0] if pano0 is not None else 2.0
    left_in, top_in = 0.3, 0.3
    tile_h_in = tile_width_in * aspect
    pano_w_in = tile_h_in * pano_aspect
    fig_w, fig_h = left_in + tile_width_in + pano_w_in, top_in + max(len(rows), 1) * tile_h_in
    fig = new_figure(fig_w, fig_h, dpi)
    gap = 0.03
    for i, (d, img, pano) in enumerate(rows):
        y = 1 - (top_in + (i + 1) * tile_h_in) / fig_h
        h = tile_h_in / fig_h
        for x0_in, w_in, im, title, missing in (
            (left_in, tile_width_in, img, "Image", "no image.png"),
            (left_in + tile_width_in, pano_w_in, pano, "Panorama", f"no {PANORAMA_FILE}"),
        ):
            x, w = x0_in / fig_w, w_in / fig_w
            rect = (
                x + gap * tile_width_in / fig_w,
                y + gap * h,
                w - 2 * gap * tile_width_in / fig_w,
                h * (1 - 2 * gap),
            )
            _tile(fig, rect, im, title if i == 0 else None, missing)
        _row_text(fig, 0.5 * left_in / fig_w, 1 - (top_in + (i + 0.5) * tile_h_in) / fig_h, _cell_label(str(d)), 6)
    return save_png(fig, out_png, dpi=dpi, facecolor="white")


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

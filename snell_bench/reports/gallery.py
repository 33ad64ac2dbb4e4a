"""The HTML report's gallery: one row per group of cells (scene-variation / object), its images copied
beside the report, and the |error| map each metric was computed from.

A row shows the group's object-free input I⁻ (``I_minus.png``), the reference render, the metric
mask, then, per method, the cell's image, its |error| map and its panorama (cells that have a
``panorama.png``); each tile carries its cell's metrics (:func:`gallery`).

Conventions:
    - Images: what the page shows is copied under ``<report>/images/``, so the report survives
      deleting ``runs/``. Names are deterministic, ``<slug>_<hash>_<kind>_<size>.<ext>``: the slug
      of the cell (or group) folder, the first 8 hex digits of the SHA-1 of that folder and the
      kind (unique whatever the slug dropped), the kind (``image``, ``error``, ...) and ``thumb``
      or ``large``. The thumbnail's longest side is :data:`THUMB_PX` pixels, the larger copy's at
      most :data:`LARGE_PX` (never enlarged), both resampled with Lanczos (the error map with a
      box filter). Photographs (I⁻, reference, image, panorama) are JPEG (quality
      :data:`JPEG_QUALITY`, no chroma subsampling); the mask and the error map are PNG, lossless,
      so the error map's colours are its values.
    - |error| map (:func:`error_map`): the metrics protocol of the cell (``metrics.protocol``,
      recorded in ``metrics.json``) applied to its 8-bit files ``image.png``, ``reference.png`` and
      ``mask.png`` (a pixel is scored where the mask is >= 0.5 of full scale): both images in gray
      (``paper``: ``0.299 R + 0.587 G + 0.114 B`` in float64; ``authors``: their float32 gray), the
      generated gray values inside the mask histogram-matched to the reference's by
      :func:`snell_bench.metrics.match_histogram_masked` (``paper``: skimage's CDF matching;
      ``authors``: their 256-bin matching, then clamped to [0, 1]), and ``|matched - reference|``
      inside the mask (NaN outside). Its mean over the mask is the MAE of the PNG files, which
      differs from the recorded MAE (computed on the unrounded image) within the 8-bit rounding.
    - Colour (:func:`colorize_error`): matplotlib's ``magma`` in :data:`ERROR_LEVELS` entries, a
      value ``v`` drawn as entry ``round(min(v / scale, 1) * 255)``: 0 black, ``scale`` and above
      pale yellow. One scale for the whole report (:func:`error_scale`): the smallest of
      :data:`ERROR_SCALES` at or above the median over the cells of each cell's 95th percentile.
      Pixels outside the mask show the reference's gray levels mapped to [160, 224], a neutral
      context that is no colour of the map.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from snell_bench.utils.io import atomic_write

from .canvas import open_image
from .collect import recorded_metrics
from .figures import PANORAMA_FILE, figure_rows, method_columns
from .spec import metric_spec
from .swept import DEFAULT_IOR, ior_label
from .tables import method_labels
from .text import is_missing, one_line, reason, slug

__all__ = [
    "THUMB_PX",
    "LARGE_PX",
    "JPEG_QUALITY",
    "ERROR_COLORMAP",
    "ERROR_LEVELS",
    "ERROR_SCALES",
    "CAPTION_METRICS",
    "Tile",
    "MetricValue",
    "MethodCell",
    "GalleryRow",
    "Gallery",
    "error_map",
    "error_scale",
    "error_lut",
    "colorize_error",
    "image_name",
    "metric_values",
    "gallery",
]

THUMB_PX = 320
"""The longest side of a thumbnail, in pixels."""

LARGE_PX = 1280
"""The longest side of the larger copy a thumbnail links to, at most (smaller images keep their size)."""

JPEG_QUALITY = 90
"""The JPEG quality of the photographs' copies."""

ERROR_COLORMAP = "magma"
"""The matplotlib colour map of the |error| maps."""

ERROR_LEVELS = 256
"""The number of colours of the |error| map (8 bits)."""

ERROR_SCALES = (0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 1.0)
"""The |error| values (gray levels, 1 = full range) the colour scale's top may take."""

CAPTION_METRICS = ("psnr", "mae", "lpips", "lpips_box", "clip", "image_reward", "psnr_true")
"""The metrics a method tile's caption shows first, in order, where any cell records them; every
other recorded metric (users' metrics) follows."""

_PHOTO = {"input", "reference", "image", "panorama"}


@dataclass(frozen=True)
class Tile:
    """One image of the gallery: its thumbnail and larger copy (paths relative to the report)."""

    kind: str
    thumb: str
    large: str
    width: int
    height: int
    alt: str


@dataclass(frozen=True)
class MetricValue:
    """One metric of a cell as a caption shows it: ``text`` is "—" where ``value`` is NaN, and
    ``reason`` says why."""

    name: str
    label: str
    value: float
    text: str
    reason: str | None = None


@dataclass
class MethodCell:
    """One method's cell of a gallery row (``image`` None where it has no image, with ``status``
    and ``reason`` saying why)."""

    method: str
    label: str
    cell_dir: str | None
    status: str
    reason: str | None
    metrics: list[MetricValue] = field(default_factory=list)
    protocol: str = "paper"
    image: Tile | None = None
    error: Tile | None = None
    error_mean: float = float("nan")
    error_reason: str | None = None
    panorama: Tile | None = None


@dataclass
class GalleryRow:
    """One group of cells: scene, variation, object, and its tiles."""

    scene: str
    variation: int
    object: str
    ior: str | None
    input: Tile | None
    reference: Tile | None
    mask: Tile | None
    mask_pixels: int
    cells: list[MethodCell]


@dataclass
class Gallery:
    """Every row, the methods (the columns, in order, with their labels) and the |error| scale."""

    rows: list[GalleryRow]
    methods: list[tuple[str, str]]
    scale: float
    files: list[Path]


# --------------------------------------------------------------------------------------------
# |error| maps
# --------------------------------------------------------------------------------------------


def error_map(generated: np.ndarray, reference: np.ndarray, mask: np.ndarray, protocol: str = "paper") -> np.ndarray:
    """``|matched - reference|`` of the gray images inside the mask, under a metrics protocol.

    Args:
        generated: the method's image, ``uint8`` ``(H, W, 3)`` (its PNG) or float in [0, 1].
        reference: the reference render, same layout.
        mask: the scored pixels, bool ``(H, W)``.
        protocol: ``"paper"`` or ``"authors"`` (config key ``metrics.protocol``).

    Returns:
        ``(H, W)`` float64: the absolute error of the histogram-matched gray values (module
        docstring) inside ``mask``, NaN outside (all NaN for an empty mask).

    Raises:
        ValueError: the images differ in size, or an unknown ``protocol``.
    """
    from snell_bench.metrics import check_protocol, match_histogram_masked, to_gray
    from snell_bench.metrics.functional import authors_gray, authors_inputs

    mask = np.asarray(mask, dtype=bool)
    out = np.full(mask.shape, np.nan)
    if check_protocol(protocol) == "authors":
        if not mask.any():
            return out
        g, r, valid = authors_inputs(generated, reference, mask)
        g, r = authors_gray(g), authors_gray(r)
        matched = match_histogram_masked(g, r, valid, protocol="authors")
        err = (matched - r).abs()[0, 0].double().numpy()
    else:
        g, r = to_gray(generated), to_gray(reference)
        if g.shape != r.shape:
            raise ValueError(f"image sizes differ: {g.shape} vs {r.shape}")
        err = np.abs(match_histogram_masked(g, r, mask) - r)
    out[mask] = err[mask]
    return out


def error_scale(cells: Sequence[np.ndarray], scales: tuple[float, ...] = ERROR_SCALES) -> float:
    """The report's colour-scale top: the smallest of ``scales`` at or above the median over the
    cells of each cell's 95th percentile of |error| (a typical cell is drawn almost unsaturated,
    a much worse one saturates).

    Args:
        cells: the masked |error| values of each cell (NaN ignored; cells without a value skipped).
        scales: the allowed tops, ascending.

    Returns:
        The top; the largest of ``scales`` when none reaches the median, the smallest without values.
    """
    q95 = [float(np.percentile(v[np.isfinite(v)], 95)) for v in cells if np.isfinite(np.asarray(v, float)).any()]
    if not q95:
        return scales[0]
    q = float(np.median(q95))
    return next((s for s in scales if s >= q), scales[-1])


def error_lut() -> np.ndarray:
    """The colours of :data:`ERROR_COLORMAP`: ``(ERROR_LEVELS, 3)`` ``uint8``, entry k for value
    ``k / (ERROR_LEVELS - 1)`` of the scale."""
    import matplotlib

    cmap = matplotlib.colormaps[ERROR_COLORMAP].resampled(ERROR_LEVELS)
    return np.round(np.asarray(cmap(np.arange(ERROR_LEVELS)))[:, :3] * 255).astype(np.uint8)


def colorize_error(err: np.ndarray, scale: float, context: np.ndarray | None = None) -> np.ndarray:
    """An |error| map as an RGB image.

    Args:
        err: ``(H, W)``, NaN where nothing was scored.
        scale: the value drawn with the last colour (larger values too).
        context: the reference's gray levels in [0, 1] ``(H, W)``, drawn (mapped to [160, 224])
            where ``err`` is NaN; mid gray (192) without.

    Returns:
        ``(H, W, 3)`` ``uint8``: entry ``round(min(err / scale, 1) * (ERROR_LEVELS - 1))`` of
        :func:`error_lut` where ``err`` is finite.

    Raises:
        ValueError: ``scale`` is not positive.
    """
    if not scale > 0:
        raise ValueError(f"the |error| scale must be positive, got {scale}")
    err = np.asarray(err, dtype=float)
    finite = np.isfinite(err)
    if context is None:
        out = np.full(err.shape + (3,), 192, np.uint8)
    else:
        gray = np.round(160 + 64 * np.clip(np.asarray(context, float), 0, 1)).astype(np.uint8)
        out = np.repeat(gray[..., None], 3, axis=-1)
    idx = np.round(np.clip(err[finite] / scale, 0, 1) * (ERROR_LEVELS - 1)).astype(int)
    out[finite] = error_lut()[idx]
    return out


# --------------------------------------------------------------------------------------------
# Copies
# --------------------------------------------------------------------------------------------


def image_name(folder: str, kind: str, size: str, ext: str) -> str:
    """The file name of a copy: ``<slug>_<hash>_<kind>_<size>.<ext>``.

    Args:
        folder: the cell or group folder, relative to the run directory.
        kind: ``input``, ``reference``, ``mask``, ``image``, ``error`` or ``panorama``.
        size: ``thumb`` or ``large``.
        ext: ``jpg`` or ``png``.

    Returns:
        A name of ASCII letters, digits, ``.``, ``-`` and ``_`` only; different for different
        ``(folder, kind)``.
    """
    stem = slug(folder, keep=".-", lower=False)[:60] or "cell"
    digest = hashlib.sha1(f"{folder}\0{kind}".encode()).hexdigest()[:8]
    return f"{stem}_{digest}_{kind}_{size}.{ext}"


def _save(image, path: Path, ext: str) -> Path:
    def write(f):
        if ext == "jpg":
            image.save(f, format="JPEG", quality=JPEG_QUALITY, subsampling=0)
        else:
            image.save(f, format="PNG")

    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write(path, write)


def _copies(image, out_dir: Path, folder: str, kind: str, alt: str, written: list[Path]) -> Tile:
    """The thumbnail and the larger copy of a PIL image under ``out_dir / "images"``."""
    from PIL import Image

    ext = "jpg" if kind in _PHOTO else "png"
    image = image.convert("RGB") if kind != "mask" else image.convert("L")
    resample = Image.Resampling.BOX if kind == "error" else Image.Resampling.LANCZOS
    names = {}
    thumb_size = image.size
    for size, px in (("large", LARGE_PX), ("thumb", THUMB_PX)):
        copy = image.copy()
        copy.thumbnail((px, px), resample=resample)
        name = image_name(folder, kind, size, ext)
        written.append(_save(copy, out_dir / "images" / name, ext))
        names[size] = f"images/{name}"
        thumb_size = copy.size
    return Tile(kind, names["thumb"], names["large"], thumb_size[0], thumb_size[1], alt)


# --------------------------------------------------------------------------------------------
# The gallery
# --------------------------------------------------------------------------------------------


def _cell_error(d: Path, protocol: str, root: Path) -> tuple[np.ndarray | str, np.ndarray | None]:
    """The |error| map of the cell in folder ``d`` and its reference's gray levels, or the reason
    there is none (a string) and None."""
    from snell_bench.metrics import to_gray

    img, ref, mask = (open_image(d / n, root) for n in ("image.png", "reference.png", "mask.png"))
    if img is None or ref is None or mask is None:
        return "no image.png, reference.png or mask.png in the cell", None
    ref_rgb = np.asarray(ref.convert("RGB"))
    mask_b = np.asarray(mask.convert("L")) >= 128
    if not mask_b.any():
        return "empty mask: no pixel is scored", None
    try:
        err = error_map(np.asarray(img.convert("RGB")), ref_rgb, mask_b, protocol)
    except ValueError as e:
        return str(e), None
    return err, to_gray(ref_rgb)


def metric_values(row: pd.Series, metrics: list[str]) -> list[MetricValue]:
    """A cell's ``metrics`` as a caption shows them, each missing one with its reason: the cell's
    status and reason when it is not ok, else its recorded ``missing.<metric>``."""
    out = []
    for m in metrics:
        spec = metric_spec(m)
        v = row.get(m)
        v = float("nan") if is_missing(v) else float(v)
        why = None
        if math.isnan(v):
            if row.get("status") != "ok":
                why = f"{row.get('status')}: {reason(row.get('reason'))}"
            else:
                why = reason(row.get(f"missing.{m}"))
        out.append(MetricValue(m, spec.label, v, spec.fmt(None if math.isnan(v) else v), why))
    return out


def _method_cell(
    method: str,
    label: str,
    r: pd.Series,
    shown: list[str],
    what: str,
    run_dir: Path,
    out_dir: Path,
    written: list[Path],
    errors: list,
) -> MethodCell:
    """The cell of ``method`` in a gallery row from its row ``r`` of ``collect``: its ``shown``
    metrics, its image and panorama copied; its masked |error| values go to ``errors`` (coloured
    once the scale is known)."""
    cdir = str(r["cell_dir"])
    why = r.get("reason")
    why = None if is_missing(why) else one_line(why)
    cell = MethodCell(method, label, cdir, str(r["status"]), why, metric_values(r, shown))
    d = run_dir / cdir
    img = open_image(d / "image.png", run_dir) if r["status"] == "ok" else None
    if img is not None:
        cell.image = _copies(img, out_dir, cdir, "image", f"{cell.label}: {what}", written)
        protocol = r.get("protocol")
        cell.protocol = protocol = "paper" if is_missing(protocol) else str(protocol)
        err, _ = _cell_error(d, protocol, run_dir)
        if isinstance(err, str):
            cell.error_reason = err
        else:
            cell.error_mean = float(np.nanmean(err))
            errors.append((cell, protocol, err[np.isfinite(err)].astype(np.float32)))
    pano = open_image(d / PANORAMA_FILE, run_dir) if r["status"] == "ok" else None
    if pano is not None:
        cell.panorama = _copies(pano, out_dir, cdir, "panorama", f"panorama of {cell.label}: {what}", written)
    return cell


def gallery(
    df: pd.DataFrame, run_dir: str | os.PathLike, out_dir: str | os.PathLike, *, by_ior: bool = False
) -> Gallery:
    """Copy the images of every group of cells under ``out_dir / "images"`` and describe the rows.

    Args:
        df: cells from ``collect``.
        run_dir: their run directory.
        out_dir: the report folder.
        by_ior: order the rows by object, then IOR (:func:`~.figures.figure_rows`).

    Returns:
        The rows (one per ``(scene, variation, object)``, in figure order), the method columns
        (``snellcaster`` first, the others sorted) with their labels, the |error| scale and the
        files written. A group's I⁻, reference and mask are the first found among its cells'
        folders and its ``_inputs`` folder.
    """
    from PIL import Image

    run_dir, out_dir = Path(run_dir), Path(out_dir)
    df = df.dropna(subset=["scene", "variation", "object", "method"])
    methods = method_columns(df)
    labels = method_labels(df)
    shown = [m for m in CAPTION_METRICS if m in df.columns]
    shown += [m for m in recorded_metrics(df) if m not in shown]  # users' metrics (metrics.extra)
    written: list[Path] = []
    rows: list[GalleryRow] = []
    errors: list[tuple[MethodCell, str, np.ndarray]] = []  # (cell, protocol, its masked |error| values)
    for scene, variation, obj in figure_rows(df, by_ior=by_ior):
        group = df[(df["scene"].astype(str) == scene) & (df["variation"] == variation) & (df["object"] == obj)]
        folder = f"{scene}-{variation}/{obj}"
        dirs = [run_dir / d for d in group["cell_dir"]] + [
            run_dir / str(group["cell_dir"].iloc[0]).rsplit("/", 1)[0] / "_inputs"
        ]

        def first(name, dirs=dirs):
            return next((im for d in dirs if (im := open_image(d / name, run_dir)) is not None), None)

        what = f"{scene}-{variation} / {obj}"
        tiles, mask_px = {}, 0
        for kind, file, alt in (
            ("input", "I_minus.png", f"I⁻, the object-free input: {what}"),
            ("reference", "reference.png", f"reference render: {what}"),
            ("mask", "mask.png", f"metric mask: {what}"),
        ):
            im = first(file)
            tiles[kind] = None if im is None else _copies(im, out_dir, folder, kind, alt, written)
            if kind == "mask" and im is not None:
                mask_px = int((np.asarray(im.convert("L")) >= 128).sum())
        cells = []
        for m in methods:
            sel = group[group["method"] == m]
            if sel.empty:
                cells.append(MethodCell(m, labels.get(m, m), None, "not run", "no cell of this method in this group"))
                continue
            cells.append(_method_cell(m, labels.get(m, m), sel.iloc[0], shown, what, run_dir, out_dir, written, errors))
        ior = ior_label(obj)
        rows.append(
            GalleryRow(
                scene,
                int(variation),
                obj,
                None if ior == DEFAULT_IOR else ior,
                tiles["input"],
                tiles["reference"],
                tiles["mask"],
                mask_px,
                cells,
            )
        )
    scale = error_scale([v for _, _, v in errors])
    for cell, protocol, _ in errors:  # computed again: one map at a time in memory, whatever the grid's size
        err, context = _cell_error(run_dir / str(cell.cell_dir), protocol, run_dir)
        rgb = Image.fromarray(colorize_error(err, scale, context))
        cell.error = _copies(rgb, out_dir, str(cell.cell_dir), "error", f"|error| map of {cell.label}", written)
    return Gallery(rows, [(m, labels.get(m, m)) for m in methods], scale, written)

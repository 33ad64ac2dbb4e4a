"""Scoring one image against one kit row, in one call: the protocol, masks and metrics of the grid.

    >>> from snell_bench.kit import load_kit, score_image                     # doctest: +SKIP
    >>> kit = load_kit("kits/smoke")                                          # doctest: +SKIP
    >>> score_image("mine/kitchen-0/sphere.png", kit.row("kitchen-0/sphere"), kit)["metrics"]  # doctest: +SKIP
    {'psnr': 24.9, 'mae': 0.036, 'lpips': None, 'clip': None, 'image_reward': None, 'psnr_true': 23.1}

The result is what a grid cell of the same image records under ``metrics`` and ``missing``
(:func:`~snell_bench.metrics.score_cell` with the kit's scoring settings, ``kit.json``'s
``scoring``): the same image scores to the same bits either way.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from snell_bench.kit.read import Kit, KitError, load_kit, read_image
from snell_bench.kit.schema import KIT_VERSION
from snell_bench.metrics import load_scorers, score_cell
from snell_bench.utils.io import saved_pixels

__all__ = ["score_image", "NO_REFERENCE"]

#: The reason a kit row without a reference gives its reference metrics, where it records none.
NO_REFERENCE = "the kit has no reference for this group"


#: The scoring settings that choose the weight-backed scorers (``metrics.<key>``).
_WEIGHT_KEYS = ("lpips_weights", "clip_weights", "image_reward_python")


@functools.lru_cache(maxsize=4)
def _scorers(*weights: Any):
    """The scorers of these weights, built once per process: a notebook scoring a kit row by row
    loads LPIPS and CLIP once, not per image."""
    return load_scorers(dict(zip(_WEIGHT_KEYS, weights)))


def _pixels(image: Any, size: tuple[int, int]) -> tuple[np.ndarray, Path | None]:
    """``image`` as ``(H, W, 3)`` float32 in [0, 1] and its file, if it is one."""
    w, h = size
    if isinstance(image, (str, os.PathLike)):
        path = Path(image).expanduser().resolve()
        return read_image(path.parent, path.name, size).astype(np.float32) / np.float32(255), path
    if hasattr(image, "convert") and hasattr(image, "size"):  # a PIL image
        image = np.asarray(image.convert("RGB"))
    if hasattr(image, "detach"):  # a torch tensor (1, 3, H, W) or (3, H, W)
        t = image.detach().cpu()
        image = (t[0] if t.ndim == 4 else t).permute(1, 2, 0).numpy()
    a = np.asarray(image)
    if a.shape != (h, w, 3):
        raise KitError(
            f"the image is {a.shape}; the group's camera is {w} x {h}: give an (H, W, 3) = ({h}, {w}, 3) image"
        )
    if a.dtype == np.uint8:
        return a.astype(np.float32) / np.float32(255), None
    return a.astype(np.float32), None


def score_image(
    image: Any,
    row: Mapping[str, Any],
    kit: Kit | str | os.PathLike,
    *,
    scorers: Mapping[str, Any] | None = None,
    scoring: Mapping[str, Any] | None = None,
) -> dict:
    """Every metric of ``image`` for the group of ``row``, as a grid cell records them.

    Args:
        image: a file (PNG or JPEG), a PIL image, an ``(H, W, 3)`` array (``uint8``, or float in
            [0, 1]) or a ``(1, 3, H, W)`` / ``(3, H, W)`` tensor, of the row's ``width`` x ``height``.
        row: the group's row (:meth:`~snell_bench.kit.read.Kit.row`, or a row of the manifest read
            with pandas or ``datasets``).
        kit: the kit (:func:`~snell_bench.kit.read.load_kit`) or its folder; the row's files are read
            inside it only.
        scorers: the weight-backed scorers (:func:`~snell_bench.metrics.load_scorers`); None: built
            from the kit's scoring settings (LPIPS, CLIP, ImageReward missing with the reason where
            their weights are not set), built once per process for the same weights.
        scoring: settings that replace the kit's (``protocol``, ``files``, ``lpips_box_range``,
            ``score_file``, ``extra``, and the weights' keys of ``metrics``).

    Returns:
        ``{"metrics": {name: float | None}, "missing": {name: reason}, "notes": ..., "protocol": ...}``.

    Raises:
        KitError: a row of another schema version, an image of another size or unreadable.
    """
    kit = kit if isinstance(kit, Kit) else load_kit(kit)
    row = dict(row)
    if row.get("schema_version") != KIT_VERSION:
        raise KitError(
            f"the row {row.get('id')!r} has schema version {row.get('schema_version')!r}; this snell_bench reads "
            f"{KIT_VERSION!r}: export the kit again (job=export)"
        )
    s = {**(kit.meta.get("scoring") or {}), **(scoring or {})}
    size = (int(row["width"]), int(row["height"]))
    pixels, path = _pixels(image, size)
    if s.get("score_file", True):
        pixels = saved_pixels(pixels)
    reference, mask = kit.array(row, "reference_float"), kit.array(row, "metric_mask")
    true, object_mask = kit.array(row, "true_render_float"), kit.array(row, "object_mask")
    if scorers is None:
        scorers = _scorers(*(s.get(k) for k in _WEIGHT_KEYS))
    return score_cell(
        pixels,
        reference,
        mask,
        str(row["clip_prompt"]),
        scorers,
        reference_reason=row.get("reference_reason") or NO_REFERENCE,
        true_render=true,
        object_mask=object_mask if true is not None else None,
        generated_path=path,
        protocol=str(s.get("protocol", "paper")),
        files=str(s.get("files", "png")),
        lpips_box_range=str(s.get("lpips_box_range", "signed")),
        reference_is_jpeg=row.get("reference_renderer") == "cycles",
        extra=tuple(str(m) for m in (s.get("extra") or ())),
    )

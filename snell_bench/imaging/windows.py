"""Destination windows of a pyramid warp: the part of the destination that holds a map's valid
pixels, aligned so that every pyramid level of the window is a sub-window of the full level.

Convention:
    - Maps ``(Bc, H', W', 2)`` as :mod:`snell_bench.imaging.coord_maps` (NaN where invalid); levels
      ``floor(n / 2)`` per level like ``pyrdown``'s; a window is a pair of slices at level 0, level ``k``
      of it starts at ``start >> k``.
"""

from __future__ import annotations

import torch

from snell_bench.utils.tensors import is_meta

__all__ = ["level_sizes", "roi_window", "paste_window"]

Size = tuple[int, int]


def level_sizes(size: Size, levels: int) -> list[Size]:
    """The ``(h, w)`` of each of ``levels`` destination levels of a level-0 ``size``, finest first."""
    sizes = [tuple(size)]
    for _ in range(levels - 1):
        h, w = sizes[-1]
        sizes.append((max(h // 2, 1) if h > 1 else 1, max(w // 2, 1) if w > 1 else 1))
    return sizes


def roi_window(c: torch.Tensor, levels: int, dest_wrap_x: bool, margin: int) -> tuple[slice, slice, bool] | None:
    """The destination window that holds every valid pixel of map ``c`` with ``margin`` invalid
    pixels of the coarsest level around it, aligned to ``2**(levels - 1)`` so that every level of the
    window is a sub-window of the full level. A dimension not divisible by ``2**(levels - 1)`` keeps
    its full extent (its odd-sized levels are resampled as a whole, see :func:`snell_bench.imaging.pyramid.collapse`). ``None`` when the
    window is (almost) the whole destination, or unknown (a map on ``meta``).
    The bool says whether the window keeps the full (periodic) width of a panorama destination."""
    if is_meta(c):
        return None
    ok = torch.isfinite(c[..., 0]).any(0)
    Hd, Wd = ok.shape
    if not bool(ok.any()):
        return None
    step = 2 ** (levels - 1)
    pad = max(margin * step, 8)

    def span(v: torch.Tensor, n: int) -> tuple[int, int]:
        idx = v.nonzero().squeeze(1)
        lo, hi = int(idx.min()) - pad, int(idx.max()) + 1 + pad
        if n % step:  # an odd-sized level is upsampled with a resampling of its whole extent
            return 0, n
        return max(lo // step * step, 0), min(-(-hi // step) * step, n)

    y0, y1 = span(ok.any(1), Hd)
    xv = ok.any(0)
    x0, x1 = span(xv, Wd)
    full_width = False
    if dest_wrap_x and (x0 == 0 or x1 == Wd):  # the valid region may cross the seam: keep the width
        x0, x1, full_width = 0, Wd, True
    if (y1 - y0) * (x1 - x0) > 0.8 * Hd * Wd:
        return None
    return slice(y0, y1), slice(x0, x1), full_width


def paste_window(part: torch.Tensor, size: Size, ys: slice, xs: slice, k: int, fill) -> torch.Tensor:
    """``part`` (a level-``k`` window) placed into a full level of ``size`` filled with ``fill``."""
    out = part.new_full(part.shape[:-2] + tuple(size), fill)
    y0, x0 = ys.start >> k, xs.start >> k
    out[..., y0 : y0 + part.shape[-2], x0 : x0 + part.shape[-1]] = part
    return out

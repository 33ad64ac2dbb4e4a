"""Backward coordinate maps as the pyramid warps read them: validity, the next coarser level, the
local stretch and the source level that matches it.

Convention:
    - A map ``c`` is ``(Bc, H', W', 2)``: SOURCE pixel coordinates ``(x, y)`` of every destination
      pixel, integer values at pixel centres, NaN where the warp is invalid (the layout
      :func:`prepare_map` returns).
    - ``period``: the width of a panorama source (x is periodic: differences are taken the short way
      round), ``None`` for a plain image.
    - ``dest_wrap_x``: the destination is a panorama (its left and right columns are neighbours).

Branches of a map:
    A map may be piecewise smooth: π^R is the identity outside a glass object and a refraction inside,
    and a refraction has further seams (grazing rays, total internal reflection). A finite difference
    across such a seam measures the seam's jump, not the map's Jacobian. Within one branch the
    difference between neighbouring pixels varies slowly; a difference ``d`` between two pixels is
    therefore a JUMP (its two pixels lie on different branches) when it disagrees with every valid
    difference next to it along the same axis: ``|d - e| > JUMP_REL * max(|d|, |e|) + JUMP_ABS`` for
    each neighbouring difference ``e`` (there is at least one). With ``JUMP_REL = 0.75`` a branch's
    Jacobian may change by a factor of up to 4 from one pixel to the next and still count as smooth
    (near a sphere's rim it grows by a factor of about 3 per pixel), and a jump from a region of
    stretch ``s`` is found once it exceeds about ``4 s + 2`` source pixels. A jump's two pixels are not
    neighbours: each takes the one-sided difference on its other side, and a pixel with no
    same-branch valid neighbour along either axis has no stretch (its own level:
    :func:`matching_level`).
"""

from __future__ import annotations

import torch

from snell_bench.utils.tensors import as_mask, as_tensor

__all__ = [
    "JUMP_REL",
    "JUMP_ABS",
    "unwrap",
    "prepare_map",
    "downsample_map",
    "local_stretch",
    "matching_level",
    "to_level",
    "valid_mask",
]

#: Relative disagreement (of the larger of two neighbouring differences) beyond which a difference
#: is a jump between branches (module docstring).
JUMP_REL = 0.75
#: Absolute disagreement, in level-0 source pixels, added to the relative one: differences within
#: half a pixel of each other always agree (sub-pixel noise never splits a branch).
JUMP_ABS = 0.5


def unwrap(d: torch.Tensor, period: float | None) -> torch.Tensor:
    """x differences taken the short way around a panorama of width ``period``."""
    return d if period is None else torch.remainder(d + period / 2, period) - period / 2


def prepare_map(coords, mask, src: torch.Tensor, wrap_x: bool) -> torch.Tensor:
    """``(Bc, H', W', 2)`` coordinates on ``src``'s device/dtype, NaN wherever the warp is invalid:
    non-finite, outside ``mask``, or outside the source (x only when not ``wrap_x``).

    Raises:
        ValueError: ``coords`` is not ``(H', W', 2)`` or ``(B, H', W', 2)``.
    """
    c = as_tensor(coords, dtype=src.dtype, device=src.device)
    if c.ndim == 3:
        c = c.unsqueeze(0)
    if c.ndim != 4 or c.shape[-1] != 2:
        raise ValueError(f"coords must be (H, W, 2) or (B, H, W, 2), got shape {tuple(c.shape)}")
    H, W = src.shape[-2:]
    x, y = c[..., 0], c[..., 1]
    ok = torch.isfinite(c).all(-1) & (y >= -0.5) & (y <= H - 0.5)
    if not wrap_x:
        ok &= (x >= -0.5) & (x <= W - 0.5)
    if mask is not None:
        m = as_mask(mask, c)[:, 0]
        ok = ok & m
    if ok.shape[0] != c.shape[0]:
        c = c.expand(ok.shape[0], -1, -1, -1)
    return torch.where(ok[..., None], c, torch.full_like(c, float("nan")))


def downsample_map(c: torch.Tensor, period: float | None) -> torch.Tensor:
    """The next destination level of a map: NaN-aware mean of each 2 x 2 block. Sizes follow
    ``pyrdown`` (``floor(n / 2)``), so the destination's bands line up with any image's own Laplacian
    pyramid; an odd last row / column is left to the finer level. Across a panorama source's seam, x is
    unwrapped relative to the block's first valid pixel before averaging."""
    for dim in (1, 2):
        n = c.shape[dim]
        if n % 2 and n > 1:
            c = c.narrow(dim, 0, n - 1)
    Bc, H, W, _ = c.shape
    blk = c.view(Bc, H // 2, 2, W // 2, 2, 2).permute(0, 1, 3, 2, 4, 5).reshape(Bc, H // 2, W // 2, 4, 2)
    ok = torch.isfinite(blk).all(-1)
    if period is not None:  # unwrap x relative to the block's first valid pixel
        first = ok.to(torch.uint8).argmax(-1, keepdim=True)
        ref = blk[..., 0].gather(-1, first)
        x = ref + unwrap(blk[..., 0] - ref, period)
        blk = torch.stack([x, blk[..., 1]], -1)
    n = ok.sum(-1, keepdim=True)
    total = torch.where(ok[..., None], blk, torch.zeros_like(blk)).sum(-2)
    mean = total / n.clamp_min(1)
    mean = torch.where(n > 0, mean, torch.full_like(mean, float("nan")))
    if period is not None:
        mean = torch.stack([torch.remainder(mean[..., 0] + 0.5, period) - 0.5, mean[..., 1]], -1)
    return mean


def _disagree(d: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
    """Whether neighbouring differences ``d`` and ``e`` ``(..., 2)`` lie on different branches
    (module docstring); False where ``e`` is NaN."""
    bound = JUMP_REL * torch.maximum(d.norm(dim=-1), e.norm(dim=-1)) + JUMP_ABS
    return (d - e).norm(dim=-1) > bound


def _same_branch_differences(c: torch.Tensor, dim: int, circular: bool, period: float | None):
    """Forward and backward differences ``(Bc, H', W', 2)`` of map ``c`` along ``dim`` (x unwrapped
    by ``period``), NaN where a neighbour is missing, invalid or across a jump."""
    if not circular and c.shape[dim] < 2:  # a single row or column: no neighbour along dim
        none = torch.full_like(c, float("nan"))
        return none, none
    if circular:
        d = c.roll(-1, dim) - c  # d[i] = c[i + 1] - c[i], the last one across the seam
    else:
        d = c.narrow(dim, 1, c.shape[dim] - 1) - c.narrow(dim, 0, c.shape[dim] - 1)
    d = torch.stack([unwrap(d[..., 0], period), d[..., 1]], -1)
    if circular:
        prev, nxt = d.roll(1, dim), d.roll(-1, dim)
    else:
        pad = torch.full_like(d.narrow(dim, 0, 1), float("nan"))
        prev = torch.cat([pad, d.narrow(dim, 0, d.shape[dim] - 1)], dim)
        nxt = torch.cat([d.narrow(dim, 1, d.shape[dim] - 1), pad], dim)
    has_prev, has_nxt = torch.isfinite(prev).all(-1), torch.isfinite(nxt).all(-1)
    jump = (has_prev | has_nxt) & (~has_prev | _disagree(d, prev)) & (~has_nxt | _disagree(d, nxt))
    d = torch.where(jump[..., None], torch.full_like(d, float("nan")), d)
    if circular:
        return d, d.roll(1, dim)
    pad = torch.full_like(c.narrow(dim, 0, 1), float("nan"))
    return torch.cat([d, pad], dim), torch.cat([pad, d], dim)


def local_stretch(c: torch.Tensor, period: float | None, dest_wrap_x: bool) -> torch.Tensor:
    """Local stretch ``(Bc, H', W')`` of a map: the larger norm of its two finite-difference Jacobian
    columns, in source pixels per destination pixel. Each column is the central difference where both
    neighbours along its axis are valid and on the pixel's branch, else the one-sided difference to
    the one that is; NaN where neither axis has such a neighbour.

    Examples:
        Stretch 1 left of a jump of 40 pixels, 3 right of it; no neighbour across it is used:

        >>> x = torch.tensor([0.0, 1.0, 2.0, 42.0, 45.0, 48.0])
        >>> c = torch.stack([x, torch.zeros(6)], -1)[None, None]  # one row: (1, 1, 6, 2)
        >>> local_stretch(c, None, False)[0, 0].tolist()
        [1.0, 1.0, 1.0, 3.0, 3.0, 3.0]
    """

    def column(dim: int, circular: bool) -> torch.Tensor:
        fwd, bwd = _same_branch_differences(c, dim, circular, period)
        return torch.nanmean(torch.stack([fwd, bwd]), 0).norm(dim=-1)

    return torch.fmax(column(2, dest_wrap_x), column(1, False))


def matching_level(c: torch.Tensor, k: int, period: float | None, dest_wrap_x: bool) -> torch.Tensor:
    """The source level whose pixel size matches a destination level-``k`` pixel of map ``c``:
    ``log2`` of :func:`local_stretch` in level-0 source pixels; where the stretch is unknown (no
    valid same-branch neighbour), ``k``, the destination level's own scale (level 0 for a full-size
    map: plain sampling, no prefilter)."""
    level = torch.log2(local_stretch(c, period, dest_wrap_x))
    return torch.where(torch.isnan(level), torch.full_like(level, float(k)), level)


def to_level(c: torch.Tensor, size0: tuple[int, int], size: tuple[int, int], wrap_x: bool) -> torch.Tensor:
    """Level-0 source coordinates scaled to a source level of ``size``: ``x_k = (x + 0.5) W_k / W - 0.5``
    (likewise ``y``), clamped to the level's area (x only when not ``wrap_x``)."""
    if tuple(size) == tuple(size0):
        return c
    (H, W), (h, w) = size0, size
    x = (c[..., 0] + 0.5) * (w / W) - 0.5
    y = ((c[..., 1] + 0.5) * (h / H) - 0.5).clamp(-0.5, h - 0.5)
    if not wrap_x:
        x = x.clamp(-0.5, w - 0.5)
    return torch.stack([x, y], -1)


def valid_mask(c: torch.Tensor, B: int) -> torch.Tensor:
    """``(B, 1, H', W')`` bool: where map ``c`` is finite, broadcast to a batch of ``B``."""
    ok = torch.isfinite(c[..., 0])[:, None]
    return ok.expand(B, -1, -1, -1) if ok.shape[0] < B else ok

"""Gaussian and Laplacian pyramids without padding, and warping through them.

Convention:
    - Images: float tensors ``(B, C, H, W)``. Level ``k + 1`` of a pyramid is ``pyrdown`` of level ``k``:
      size ``floor(H_k / 2) x floor(W_k / 2)``, no padding to powers of two (720 x 1280 gives 360 x 640,
      ..., 45 x 80). Pyramids are lists, finest first; the last entry of a Laplacian pyramid is the
      low-pass residual (the coarsest Gaussian level).
    - Coordinate maps: ``(H', W', 2)`` or ``(B, H', W', 2)`` (torch or numpy) SOURCE pixel coordinates
      ``(x, y)`` of every destination pixel, integer values at pixel centres, NaN where the warp is invalid
      (backward warps, as :func:`~snell_bench.imaging.remap.remap`).
    - Masks: bool ``(B, 1, H, W)`` or ``(H, W)`` (broadcast over the batch); returned masks are
      ``(B, 1, H, W)``.
    - Level geometry: a level-0 pixel coordinate ``x`` is ``x_k = (x + 0.5) * W_k / W - 0.5`` at level
      ``k`` (and likewise for ``y``). That is ``(x + 0.5) / 2**k - 0.5`` when sizes halve exactly; for odd
      sizes the actual size ratio is used, which is the geometry of ``pyrdown``'s resampling.
    - ``wrap_x=True`` marks a 360° panorama, periodic in x: pyramids are blurred with circular padding in
      x (exact for even widths) and sampling wraps around the seam.
    - Tensors on the ``meta`` device (:func:`~snell_bench.utils.tensors.is_meta`: shapes, no data) take
      the general path wherever the real one reads values to save work (an all-valid mask, the levels a
      map samples, the window around its valid pixels): the same output shapes, nothing read; the
      pyramids and warps run once per input shape there
      (:func:`~snell_bench.utils.tensors.meta_shape_cache`).

Warping through a pyramid:
    The destination pyramid's geometry comes from the coordinate map itself: level ``k + 1`` of the map
    averages the coordinates of the valid pixels of each 2 x 2 block of level ``k``; level sizes are
    ``floor(n / 2)`` like ``pyrdown``'s, so the bands line up with any image's own
    :func:`laplacian_pyramid` and can be blended with it (an odd last row / column lives only at the
    finer level; the coarse coordinate of an odd-sized level is off by at most half a coarse pixel from
    ``pyrdown``'s resampling geometry). Across the seam of a panorama source, x is unwrapped relative to
    the block's first valid pixel before averaging. A coarse destination pixel is valid if ANY of its
    fine pixels is valid, and masked upsampling (normalised by the upsampled mask) never mixes invalid
    pixels into valid ones.

    Each destination level ``k`` samples the source's Gaussian pyramid at the level whose pixel size
    matches the map's local footprint: ``log2 s`` with ``s`` the local stretch (level-0 source pixels per
    destination level-``k`` pixel: the larger column norm of the map's finite-difference Jacobian,
    from valid neighbours on the pixel's own branch of the map only, so a seam such as an object's
    silhouette in π^R does not coarsen the pixels beside it:
    :func:`~snell_bench.imaging.coord_maps.local_stretch`), clamped to ``[0, levels - 1]``, fractional
    levels blending the two nearest linearly. For the identity map that is level ``k`` (and the warp is
    the source itself, bit for bit, see :func:`~snell_bench.imaging.remap.remap`); where the map
    compresses it is coarser (no aliasing), where it magnifies it is finer (no blur). :func:`lod_warp` returns the finest such level, a per-pixel level-of-detail
    (trilinear mip-map) warp. :func:`pyramid_warp` returns the destination's Laplacian pyramid
    ``D_k = A_k - up(A_{k+1})`` of the warped Gaussian levels ``A_k`` (masked upsampling), for blending
    band by band. For the identity map (sizes divisible by ``2**(levels - 1)``) ``D`` is the source's
    Laplacian pyramid; whatever the map, ``D`` collapses (masked :func:`collapse`) to ``A_0``, which
    ``pyramid_warp(..., collapse=True)`` returns directly: it equals ``lod_warp``, and equals :func:`remap`
    wherever the map does not compress, so integer translations and magnifications are exactly remap's.
    Warping the source's Laplacian bands instead (band ``k`` at level ``k``) does not have this property:
    the destination's upsampling differs from the source's where the map stretches, which sharpens
    magnified regions and blurs the coarse bands of sub-pixel moves.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from kornia.filters import filter2d

from snell_bench.imaging.coord_maps import downsample_map, matching_level, prepare_map, to_level, valid_mask
from snell_bench.imaging.remap import remap
from snell_bench.imaging.windows import level_sizes, paste_window, roi_window
from snell_bench.utils.tensors import as_mask, is_meta, meta_shape_cache

__all__ = [
    "gaussian_pyramid",
    "laplacian_pyramid",
    "laplacian_from_gaussian",
    "collapse",
    "pyramid_warp",
    "warped_bands",
    "lod_warp",
]

Size = tuple[int, int]


# ----------------------------------------------------------------------------------- pyramids
def _circular_cols(img: torch.Tensor, pad: int) -> torch.Tensor:
    """``img`` with ``pad`` columns wrapped around on each side (any width)."""
    W = img.shape[-1]
    idx = torch.arange(-pad, W + pad, device=img.device) % W
    return img.index_select(-1, idx)


@functools.lru_cache(maxsize=16)
def _gauss5(device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """kornia's 5 x 5 pyramid kernel ``(1, 5, 5)`` (the outer product of ``[1, 4, 6, 4, 1] / 16``),
    kept on each device: kornia's ``pyrdown`` / ``pyrup`` build it on the host at every call, a
    host-to-device copy per level on a GPU."""
    k = torch.tensor([1.0, 4.0, 6.0, 4.0, 1.0])
    return (torch.outer(k, k)[None] / 256.0).to(device=device, dtype=dtype)


def pyrdown(img: torch.Tensor) -> torch.Tensor:
    """kornia's ``pyrdown`` (5-tap blur with reflected borders, then bilinear resampling to
    ``floor(n / 2)``) with its kernel kept on ``img``'s device: the same numbers."""
    h, w = img.shape[-2:]
    blur = filter2d(img, _gauss5(img.device, img.dtype), "reflect")
    return F.interpolate(blur, size=[int(float(h) / 2.0), int(float(w) / 2.0)], mode="bilinear", align_corners=False)


def pyrup(img: torch.Tensor) -> torch.Tensor:
    """kornia's ``pyrup`` (bilinear upsampling to ``2 n``, then the 5-tap blur with reflected
    borders) with its kernel kept on ``img``'s device: the same numbers."""
    h, w = img.shape[-2:]
    up = F.interpolate(img, size=(h * 2, w * 2), mode="bilinear", align_corners=False)
    return filter2d(up, _gauss5(img.device, img.dtype), "reflect")


def _down(img: torch.Tensor, wrap_x: bool) -> torch.Tensor:
    if not wrap_x:
        return pyrdown(img)
    # 4 wrapped columns per side cover the 5-tap blur; pyrdown halves them to 2 per side
    return pyrdown(_circular_cols(img, 4))[..., 2:-2]


def _up(img: torch.Tensor, size: Size, wrap_x: bool) -> torch.Tensor:
    """``pyrup`` of ``img`` brought to ``size``: cropped when the doubled size is larger, resampled
    when it is smaller (a level of floor(n / 2) pixels under an odd-sized one)."""
    if wrap_x:
        up = pyrup(_circular_cols(img, 2))[..., 4:-4]
    else:
        up = pyrup(img)
    up = up[..., : size[0], : size[1]]
    if tuple(up.shape[-2:]) != tuple(size):
        up = F.interpolate(up, size=size, mode="bilinear", align_corners=False)
    return up


def _check_levels(img: torch.Tensor, levels: int) -> None:
    if img.ndim != 4:
        raise ValueError(f"image must be (B, C, H, W), got shape {tuple(img.shape)}")
    if levels < 1:
        raise ValueError(f"levels must be >= 1, got {levels}")
    H, W = img.shape[-2:]
    if min(H, W) >> (levels - 1) < 1:
        raise ValueError(f"a {H}x{W} image has fewer than {levels} pyramid levels")


@meta_shape_cache
def gaussian_pyramid(img: torch.Tensor, levels: int, *, wrap_x: bool = False) -> list[torch.Tensor]:
    """Gaussian pyramid ``[img, pyrdown(img), ...]``, finest first.

    Args:
        img: ``(B, C, H, W)`` image.
        levels: number of levels (>= 1; the coarsest must keep at least one pixel).
        wrap_x: the image is a panorama (circular blur in x).

    Returns:
        ``levels`` tensors ``(B, C, floor(H / 2**k), floor(W / 2**k))``.

    Raises:
        ValueError: ``img`` is not 4-D, or has fewer than ``levels`` levels.

    Examples:
        >>> g = gaussian_pyramid(torch.ones(1, 1, 8, 12), 3)
        >>> [tuple(level.shape[-2:]) for level in g], round(float(g[-1].mean()), 4)
        ([(8, 12), (4, 6), (2, 3)], 1.0)
    """
    _check_levels(img, levels)
    pyr = [img]
    for _ in range(levels - 1):
        pyr.append(_down(pyr[-1], wrap_x))
    return pyr


def laplacian_pyramid(img: torch.Tensor, levels: int, *, wrap_x: bool = False) -> list[torch.Tensor]:
    """Laplacian pyramid: ``levels - 1`` band-pass levels ``G_k - up(G_{k+1})``, then the residual
    ``G_{levels-1}``. :func:`collapse` inverts it to float precision.

    Args:
        img: ``(B, C, H, W)`` image.
        levels: number of levels (as :func:`gaussian_pyramid`).
        wrap_x: the image is a panorama (circular blur and upsampling in x).

    Returns:
        ``levels`` tensors with the sizes of :func:`gaussian_pyramid`.

    Examples:
        A pyramid collapses back to its image:

        >>> img = torch.rand(1, 3, 16, 24, generator=torch.Generator().manual_seed(0))
        >>> pyr = laplacian_pyramid(img, 3)
        >>> [tuple(level.shape[-2:]) for level in pyr]
        [(16, 24), (8, 12), (4, 6)]
        >>> round(float((collapse(pyr) - img).abs().max()), 4)
        0.0
    """
    g = gaussian_pyramid(img, levels, wrap_x=wrap_x)
    return _bands(g, wrap_x) + [g[-1]]


@meta_shape_cache
def laplacian_from_gaussian(g: Sequence[torch.Tensor], *, wrap_x: bool = False) -> list[torch.Tensor]:
    """The Laplacian pyramid of an image from its Gaussian pyramid (as :func:`laplacian_pyramid`).

    Args:
        g: the image's :func:`gaussian_pyramid`.
        wrap_x: the image is a panorama.

    Returns:
        The Laplacian pyramid, ``len(g)`` levels.

    Examples:
        >>> img = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
        >>> a = laplacian_from_gaussian(gaussian_pyramid(img, 3))
        >>> b = laplacian_pyramid(img, 3)
        >>> round(float(max((x - y).abs().max() for x, y in zip(a, b))), 4)
        0.0
    """
    return _bands(g, wrap_x) + [g[-1]]


def _bands(g: Sequence[torch.Tensor], wrap_x: bool) -> list[torch.Tensor]:
    """The band-pass levels ``G_k - up(G_{k+1})`` of a Gaussian pyramid."""
    return [g[k] - _up(g[k + 1], g[k].shape[-2:], wrap_x) for k in range(len(g) - 1)]


def collapse(pyr: Sequence[torch.Tensor], masks: Sequence | None = None, *, wrap_x: bool = False) -> torch.Tensor:
    """Sum a Laplacian pyramid back into an image (finest level's size).

    With ``masks`` (one per level, bool), the upsampling is normalised by the upsampled mask, so values
    at invalid pixels never reach valid ones; pixels invalid at level 0 are 0.

    Args:
        pyr: a Laplacian pyramid, finest first (:func:`laplacian_pyramid`, :func:`pyramid_warp`).
        masks: ``None`` or one mask per level (``(H_k, W_k)`` or ``(B, 1, H_k, W_k)``).
        wrap_x: the image is a panorama (circular upsampling in x).

    Returns:
        ``(B, C, H, W)`` image.

    Examples:
        >>> img = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
        >>> round(float((collapse(laplacian_pyramid(img, 3, wrap_x=True), wrap_x=True) - img).abs().max()), 4)
        0.0
        >>> masks = [torch.ones(8 >> k, 8 >> k, dtype=torch.bool) for k in range(3)]
        >>> masks[0][0, 0] = False
        >>> out = collapse(laplacian_pyramid(img, 3), masks)
        >>> float(out[0, 0, 0, 0]), round(float((out - img)[..., 1:, 1:].abs().max()), 4)
        (0.0, 0.0)
    """
    img = pyr[-1]
    if masks is None:
        for band in reversed(pyr[:-1]):
            img = band + _up(img, band.shape[-2:], wrap_x)
        return img
    m = as_mask(masks[-1], img)
    img = torch.where(m, img, torch.zeros_like(img))
    for band, mask in zip(reversed(pyr[:-1]), reversed(masks[:-1])):
        mk = as_mask(mask, band)
        img = torch.where(mk, band + _up_masked(img, m, band.shape[-2:], wrap_x), torch.zeros_like(band))
        m = mk
    return img


def _up_masked(img: torch.Tensor, mask: torch.Tensor, size: Size, wrap_x: bool) -> torch.Tensor:
    """:func:`_up` normalised by the upsampled ``mask``: only valid pixels of ``img`` are read (an
    all-valid mask is a plain :func:`_up`)."""
    if not is_meta(mask) and bool(mask.all()):
        return _up(img, size, wrap_x)
    B = max(img.shape[0], mask.shape[0])
    img = torch.where(mask, img, torch.zeros_like(img)).expand(B, -1, -1, -1)
    w = mask.to(img.dtype).expand(B, -1, -1, -1)
    up, w = _up(torch.cat([img, w], 1), size, wrap_x).split([img.shape[1], 1], 1)  # one pyrup for both
    return up / torch.where(w > 0, w, torch.ones_like(w))


def _sample(
    images: Sequence[torch.Tensor], c: torch.Tensor, level: torch.Tensor, *, size0: Size, wrap_x: bool
) -> torch.Tensor:
    """Sample ``images[j]`` at the fractional per-pixel ``level`` ``(Bc, H', W')`` in
    ``[0, len(images) - 1]``, blending the two nearest levels linearly (bilinear within a level). Each
    level is only sampled at the pixels that use it (on ``meta``, every level at every pixel)."""
    Bc, h, w, _ = c.shape
    dense = is_meta(level)
    B, C = max(images[0].shape[0], Bc), images[0].shape[1]
    out = images[0].new_zeros(B, C, h * w)
    lo = level.floor()
    frac = level - lo
    for j, im in enumerate(images):
        wj = torch.where(lo == j, 1 - frac, torch.where(lo == j - 1, frac, torch.zeros_like(frac)))
        use = (wj > 0).any(0)
        if not dense and not bool(use.any()):
            continue
        cj = to_level(c, size0, im.shape[-2:], wrap_x)
        if im.shape[0] < B:
            im = im.expand(B, -1, -1, -1)
        if dense or bool(use.all()):
            s, _ = remap(im, cj, wrap_x=wrap_x)
            out = out + (s * wj[:, None]).flatten(2)
        else:
            idx = use.flatten().nonzero().squeeze(1)
            s, _ = remap(im, cj.flatten(1, 2)[:, idx][:, None], wrap_x=wrap_x)
            out = out.index_add(2, idx, s[:, :, 0] * wj.flatten(1)[:, idx][:, None])
    return out.view(B, C, h, w)


# ------------------------------------------------------------------------------------ warps
def _source_levels(
    maps: Sequence[torch.Tensor], levels: int, *, match_scale: bool, period: float | None, dest_wrap_x: bool
) -> list[torch.Tensor]:
    """The fractional source level sampled at each pixel of each destination level ``maps[k]``."""
    if not match_scale:
        return [torch.full_like(c[..., 0], float(k)) for k, c in enumerate(maps)]
    return [matching_level(c, k, period, dest_wrap_x).clamp(0, levels - 1) for k, c in enumerate(maps)]


def _warp_levels(
    src: torch.Tensor,
    maps: Sequence[torch.Tensor],
    levels: int,
    *,
    wrap_x: bool,
    match_scale: bool,
    dest_wrap_x: bool,
    src_pyramid: Sequence[torch.Tensor] | None = None,
) -> list[torch.Tensor]:
    """Each destination level ``maps[k]`` sampled from ``src``'s Gaussian pyramid, which is only built
    as deep as the sampled levels reach (or taken from ``src_pyramid``; on ``meta``, as deep as the
    clamp to ``levels`` allows)."""
    period = float(src.shape[-1]) if wrap_x else None
    lvls = _source_levels(maps, levels, match_scale=match_scale, period=period, dest_wrap_x=dest_wrap_x)
    if not match_scale:  # level k for map k
        depth = len(maps)
    elif is_meta(src):
        depth = levels
    else:
        depth = max(int(lv.max().ceil()) for lv in lvls) + 1
    if src_pyramid is not None and len(src_pyramid) >= depth:
        gauss = list(src_pyramid[:depth])
    else:
        gauss = gaussian_pyramid(src, depth, wrap_x=wrap_x)
    size0 = tuple(src.shape[-2:])
    return [_sample(gauss, c, lv, size0=size0, wrap_x=wrap_x) for c, lv in zip(maps, lvls)]


@meta_shape_cache
def pyramid_warp(
    src: torch.Tensor,
    coords,
    *,
    levels: int = 5,
    wrap_x: bool = False,
    collapse: bool = True,
    mask=None,
    match_scale: bool = True,
    dest_wrap_x: bool = False,
    roi: bool = False,
    roi_margin: int = 4,
    src_pyramid: Sequence[torch.Tensor] | None = None,
    gaussian: bool = False,
):
    """Laplacian pyramid warp of ``src`` through the backward map ``coords`` (module docstring).

    Args:
        src: ``(B, C, H, W)`` source image.
        coords: ``(H', W', 2)`` or ``(B, H', W', 2)`` source coordinates, NaN where invalid.
        levels: pyramid levels (1: plain :func:`remap`).
        wrap_x: the source is a panorama (periodic in x).
        collapse: return the collapsed warp, or the destination's Laplacian pyramid (to blend band by
            band, then :func:`collapse`).
        mask: optional bool ``(H', W')`` / ``(B, 1, H', W')``, ANDed with the map's validity.
        match_scale: sample each destination level from the source level matching the map's local
            stretch; ``False`` samples level ``k`` for level ``k`` (no anti-aliasing).
        dest_wrap_x: the destination is a panorama (circular upsampling and finite differences).
        roi: compute only in a window around the map's valid pixels (``roi_margin`` invalid pixels of
            the coarsest level around them, aligned to ``2**(levels - 1)``) and place it into the full
            destination: the same result (every operation reaches fewer pixels than the margin), at
            a cost proportional to the window when the valid region is small (an object's pixels).
        src_pyramid: ``gaussian_pyramid(src, levels, wrap_x=wrap_x)`` if already built (several warps
            of one image, or its own :func:`laplacian_pyramid`, share it).
        gaussian: with ``collapse=False``, return the warped Gaussian levels ``A_k`` instead of their
            bands (to edit them before :func:`warped_bands`).

    Returns:
        ``(warped (B, C, H', W'), valid (B, 1, H', W') bool)`` with ``collapse=True``, else
        ``(levels bands, levels masks)``: a Laplacian pyramid, finest first, with the sizes of
        :func:`laplacian_pyramid` (``floor(n / 2)`` per level),
        whose masked :func:`collapse` is ``warped``. Invalid pixels are 0.

    Raises:
        ValueError: ``src`` is not 4-D or has fewer than ``levels`` levels, or ``coords`` has a
            wrong shape.

    Examples:
        The identity map gives back the image, and its pyramid is the image's own:

        >>> import numpy as np
        >>> img = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0))
        >>> ys, xs = np.mgrid[0:16, 0:16].astype(np.float32)
        >>> identity = np.stack([xs, ys], -1)
        >>> out, valid = pyramid_warp(img, identity, levels=3)
        >>> round(float((out - img).abs().max()), 4), bool(valid.all())
        (0.0, True)
        >>> bands, masks = pyramid_warp(img, identity, levels=3, collapse=False)
        >>> round(float(max((b - l).abs().max() for b, l in zip(bands, laplacian_pyramid(img, 3)))), 4)
        0.0

        A shift by one pixel to the left, invalid (0) where it leaves the source:

        >>> out, valid = pyramid_warp(img, identity + [1.0, 0.0], levels=3)
        >>> round(float((out[..., :-1] - img[..., 1:]).abs().max()), 4), bool(valid[..., -1].any())
        (0.0, False)
    """
    _check_levels(src, levels)
    c = prepare_map(coords, mask, src, wrap_x)
    win = roi_window(c, levels, dest_wrap_x, roi_margin) if roi else None
    opts = dict(wrap_x=wrap_x, collapse=collapse, match_scale=match_scale, src_pyramid=src_pyramid, gaussian=gaussian)
    if win is not None:
        return _warp_window(src, c, win, levels, dest_wrap_x=dest_wrap_x, **opts)
    return _warp_pyramid(src, c, levels, dest_wrap_x=dest_wrap_x, **opts)


def _warp_window(src: torch.Tensor, c: torch.Tensor, win: tuple, levels: int, *, dest_wrap_x: bool, **opts):
    """Warp the map ``c`` ``(B, H', W', 2)`` inside its :func:`roi_window` ``win``; pasted at full size, 0 outside."""
    ys, xs, full_width = win
    part = pyramid_warp(src, c[:, ys, xs], levels=levels, dest_wrap_x=dest_wrap_x and full_width, **opts)
    sizes = level_sizes(tuple(c.shape[1:3]), levels)
    if opts["collapse"]:
        return paste_window(part[0], sizes[0], ys, xs, 0, 0.0), paste_window(part[1], sizes[0], ys, xs, 0, False)
    return (
        [paste_window(b, sizes[k], ys, xs, k, 0.0) for k, b in enumerate(part[0])],
        [paste_window(m, sizes[k], ys, xs, k, False) for k, m in enumerate(part[1])],
    )


def _warp_pyramid(src: torch.Tensor, c: torch.Tensor, levels: int, *, collapse: bool, gaussian: bool, **opts):
    """Warp the whole map ``c`` ``(B, H', W', 2)``: level 0 with ``collapse``, else ``levels`` levels, finest first."""
    B = max(src.shape[0], c.shape[0])
    if collapse:  # the destination pyramid collapses exactly to its finest level
        return _warp_levels(src, [c], levels, **opts)[0], valid_mask(c, B)
    maps = [c]
    for _ in range(levels - 1):
        maps.append(downsample_map(maps[-1], float(src.shape[-1]) if opts["wrap_x"] else None))
    warped = _warp_levels(src, maps, levels, **opts)
    masks = [valid_mask(ck, B) for ck in maps]
    return (warped if gaussian else warped_bands(warped, masks, wrap_x=opts["dest_wrap_x"])), masks


def warped_bands(levels: Sequence[torch.Tensor], masks: Sequence, *, wrap_x: bool = False) -> list[torch.Tensor]:
    """The Laplacian pyramid ``D_k = A_k - up(A_{k+1})`` (masked upsampling, 0 where invalid; the last
    entry ``A_{L-1}``) of destination Gaussian levels ``A_k`` with their masks, as
    :func:`pyramid_warp` returns it; its masked :func:`collapse` is ``A_0``.

    Args:
        levels: ``(B, C, H_k, W_k)``, finest first (``pyramid_warp(..., collapse=False, gaussian=True)``).
        masks: one bool mask per level (``(B, 1, H_k, W_k)`` or ``(H_k, W_k)``).
        wrap_x: the destination is a panorama (circular upsampling).
    """
    bands = []
    for k in range(len(levels) - 1):
        up = _up_masked(levels[k + 1], as_mask(masks[k + 1], levels[k + 1]), levels[k].shape[-2:], wrap_x)
        bands.append(torch.where(as_mask(masks[k], levels[k]), levels[k] - up, torch.zeros_like(levels[k])))
    return bands + [levels[-1]]


def lod_warp(
    src: torch.Tensor, coords, *, levels: int = 5, wrap_x: bool = False, mask=None, dest_wrap_x: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-pixel level-of-detail warp: sample ``src``'s Gaussian pyramid at level ``log2`` of the map's
    local stretch (clamped to ``[0, levels - 1]``), blending the two nearest levels.

    Where the map does not compress this is exactly :func:`remap`.

    Args:
        src: ``(B, C, H, W)`` source image.
        coords: ``(H', W', 2)`` or ``(B, H', W', 2)`` source coordinates, NaN where invalid.
        levels: levels of the source's Gaussian pyramid.
        wrap_x: the source is a panorama (periodic in x).
        mask: optional bool ``(H', W')`` / ``(B, 1, H', W')``, ANDed with the map's validity.
        dest_wrap_x: the destination is a panorama (circular finite differences).

    Returns:
        ``(warped (B, C, H', W'), valid (B, 1, H', W') bool)``; invalid pixels are 0.

    Examples:
        Halving the size samples level 1 of the source's Gaussian pyramid:

        >>> import numpy as np
        >>> img = torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(0))
        >>> ys, xs = np.mgrid[0:8, 0:8].astype(np.float32)
        >>> half = np.stack([2 * xs + 0.5, 2 * ys + 0.5], -1)
        >>> out, valid = lod_warp(img, half, levels=3)
        >>> level1 = gaussian_pyramid(img, 2)[1]
        >>> tuple(out.shape), round(float((out - level1).abs().max()), 4)
        ((1, 1, 8, 8), 0.0)
    """
    _check_levels(src, levels)
    c = prepare_map(coords, mask, src, wrap_x)
    out = _warp_levels(src, [c], levels, wrap_x=wrap_x, match_scale=True, dest_wrap_x=dest_wrap_x)[0]
    return out, valid_mask(c, out.shape[0])

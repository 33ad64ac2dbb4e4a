"""Blending warped estimates: the detail-preserving average (DPA) on whole images or per pyramid
level, the Fresnel combination of reflection and refraction colours, and the absorption of the
refracted colour along its path in the glass (:func:`absorb`).

Convention:
    - Images: float tensors ``(B, C, H, W)`` (any value range; Laplacian bands are signed). Colours
      for :func:`fresnel_combine` are sRGB-encoded in ``[0, 1]``.
    - Value domain of phi: its ``|x|`` weights favour values far from 0, so the domain matters. On
      band-pass levels (signed, centred on 0) it favours detail; on images in ``[0, 1]`` it would
      favour bright values (0.8 and 0.2 blend to 0.59). :func:`blend_images` and, with
      ``signed_lowpass``, the low-pass level of :func:`blend_pyramids` therefore map ``[0, 1]`` to
      FLUX's ``[-1, 1]`` image space (``x -> 2x - 1``) before phi and back after (0.8 and 0.2 blend
      to 0.5).
    - Masks: bool ``(B, 1, H, W)`` or ``(H, W)`` (broadcast over batch and channels,
      :func:`~snell_bench.utils.tensors.as_mask`); ``None`` means valid everywhere. Returned
      masks are ``(B, 1, H, W)``.
    - Values of an input where its mask is False are never read (they may be NaN or inf).
    - Pyramids: lists of levels, finest first, the last entry the low-pass residual
      (:mod:`snell_bench.imaging.pyramid`).
    - On the ``meta`` device (shapes, no data) the blends run once per input shape
      (:func:`~snell_bench.utils.tensors.meta_shape_cache`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.imaging.pyramid import collapse
from snell_bench.utils.tensors import as_mask, as_tensor, meta_shape_cache

__all__ = ["detail_preserving_average", "blend_images", "blend_pyramids", "fresnel_combine", "absorb"]


def _mask_like(mask, x: torch.Tensor) -> torch.Tensor:
    """A mask broadcast to ``(B, 1, H, W)`` of ``x``; ``None`` is all-valid."""
    if mask is None:
        return torch.ones_like(x[:, :1], dtype=torch.bool)
    return as_mask(mask, x).expand(x.shape[0], 1, *x.shape[-2:])


def detail_preserving_average(
    inputs: Sequence[torch.Tensor],
    masks: Sequence | None = None,
    lam: float = 0.5,
    fallback: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Detail-preserving average of the valid inputs of each pixel.

    With masks ``M_i``: ``avg = sum M_i x_i / sum M_i``, ``vavg = sum M_i |x_i| x_i / sum M_i |x_i|``
    and ``phi = avg + lam (vavg - avg)``; ``vavg = avg`` where ``sum M_i |x_i| = 0``. ``lam = 0`` is the
    masked mean; larger ``lam`` favours inputs of larger magnitude (detail, on band-pass levels).

    Args:
        inputs: ``N`` tensors ``(B, C, H, W)``.
        masks: ``N`` masks (or ``None`` entries, or ``None`` for all-valid).
        lam: detail weight ``lambda``.
        fallback: value where no input is valid; default the first input (its non-finite values
            replaced by 0).

    Returns:
        ``(blended (B, C, H, W), any_valid (B, 1, H, W) bool)``.

    Raises:
        ValueError: no input, or not as many masks as inputs.

    Examples:
        Two valid inputs 1 and 3: the mean is 2, the magnitude-weighted mean 2.5, ``lam`` blends:

        >>> x1, x3 = torch.full((1, 1, 2, 2), 1.0), torch.full((1, 1, 2, 2), 3.0)
        >>> [round(float(detail_preserving_average([x1, x3], lam=lam)[0][0, 0, 0, 0]), 4) for lam in (0, 0.5, 1)]
        [2.0, 2.25, 2.5]

        Where only one input is valid, it is the result; where none is, the fallback:

        >>> m3 = torch.tensor([[True, False], [False, False]])
        >>> out, ok = detail_preserving_average([x1, x3], [torch.zeros(2, 2, dtype=torch.bool), m3])
        >>> out[0, 0].tolist(), ok[0, 0].tolist()
        ([[3.0, 1.0], [1.0, 1.0]], [[True, False], [False, False]])
    """
    if len(inputs) == 0:
        raise ValueError("detail_preserving_average needs at least one input")
    if masks is None:
        masks = [None] * len(inputs)
    if len(masks) != len(inputs):
        raise ValueError(f"{len(inputs)} inputs but {len(masks)} masks")
    x = torch.stack(torch.broadcast_tensors(*inputs))
    m = torch.stack([_mask_like(mk, x[0]) for mk in masks])
    x = torch.where(m, x, torch.zeros_like(x))
    w = m.to(x.dtype)
    count = w.sum(0)
    any_valid = count > 0
    avg = x.sum(0) / count.clamp_min(1.0)
    a = x.abs()
    norm = a.sum(0)
    has_norm = norm > 0
    vavg = torch.where(has_norm, (a * x).sum(0) / torch.where(has_norm, norm, torch.ones_like(norm)), avg)
    phi = avg + lam * (vavg - avg)
    if fallback is None:
        first = inputs[0]
        fallback = torch.where(torch.isfinite(first), first, torch.zeros_like(first))
    return torch.where(any_valid, phi, fallback), any_valid


def _signed_dpa(inputs, masks, lam: float, fallback: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`detail_preserving_average` of ``[0, 1]`` values computed in ``[-1, 1]`` and mapped back;
    the fallback (default: the first input, non-finite values 0) is returned unchanged."""
    if fallback is None:
        first = inputs[0]
        fallback = torch.where(torch.isfinite(first), first, torch.zeros_like(first))
    out, ok = detail_preserving_average([2.0 * x - 1.0 for x in inputs], masks, lam)
    return torch.where(ok, (out + 1.0) / 2.0, fallback), ok


@meta_shape_cache
def blend_images(
    images: Sequence[torch.Tensor],
    masks: Sequence | None = None,
    lam: float = 0.5,
    fallback: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Detail-preserving average of whole images in ``[0, 1]``, computed in FLUX's ``[-1, 1]``
    image space: ``(phi(2 x_i - 1) + 1) / 2``.

    Args:
        images: ``N`` tensors ``(B, C, H, W)`` in ``[0, 1]``.
        masks: ``N`` masks (or ``None`` entries, or ``None`` for all-valid).
        lam: detail weight ``lambda``.
        fallback: value where no input is valid (``[0, 1]``); default the first input (non-finite
            values replaced by 0).

    Returns:
        ``(blended (B, C, H, W) in [0, 1], any_valid (B, 1, H, W) bool)``.

    Examples:
        0.8 and 0.2 are 0.6 and -0.6 in ``[-1, 1]``: mean and magnitude-weighted mean are 0, so the
        blend is 0.5 whatever ``lam`` (in ``[0, 1]`` directly, ``lam = 0.5`` would give 0.59):

        >>> a, b = torch.full((1, 1, 1, 1), 0.8), torch.full((1, 1, 1, 1), 0.2)
        >>> [round(float(blend_images([a, b], lam=lam)[0]), 4) for lam in (0, 0.5, 1)]
        [0.5, 0.5, 0.5]
        >>> round(float(detail_preserving_average([a, b], lam=0.5)[0]), 4)
        0.59
    """
    if len(images) == 0:
        raise ValueError("blend_images needs at least one image")
    return _signed_dpa(images, masks, lam, fallback)


@meta_shape_cache
def blend_pyramids(
    level_lists: Sequence[Sequence[torch.Tensor]],
    mask_lists: Sequence | None = None,
    lam: float = 0.5,
    fallback_levels: Sequence[torch.Tensor] | None = None,
    *,
    wrap_x: bool = False,
    signed_lowpass: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Detail-preserving average of several pyramids, level by level, then collapsed.

    Args:
        level_lists: one pyramid per input (e.g. ``pyramid_warp(..., collapse=False)[0]`` or
            ``laplacian_pyramid``), all with the same level sizes.
        mask_lists: one list of per-level masks per input (``pyramid_warp(..., collapse=False)[1]``);
            ``None`` (for an input, or for all) means valid everywhere.
        lam: detail weight of :func:`detail_preserving_average`.
        fallback_levels: a pyramid used at pixels of a level where no input is valid; default the
            first input's levels.
        wrap_x: the destination is a panorama (circular collapse).
        signed_lowpass: the pyramids are of images in ``[0, 1]``: phi on the low-pass level is
            computed in ``[-1, 1]`` (as :func:`blend_images`); the band-pass levels are signed already
            (phi is homogeneous, so scaling them by 2 would change nothing). With one level this is
            :func:`blend_images`.

    Returns:
        ``(image (B, C, H, W), any_valid (B, 1, H, W) bool)``; ``any_valid`` is the finest level's.

    Raises:
        ValueError: the pyramids have different numbers of levels.

    Examples:
        Blending a pyramid with itself collapses to its image:

        >>> from snell_bench.imaging.pyramid import laplacian_pyramid
        >>> img = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(0))
        >>> pyr = laplacian_pyramid(img, 3)
        >>> out, ok = blend_pyramids([pyr, pyr])
        >>> round(float((out - img).abs().max()), 4), bool(ok.all())
        (0.0, True)
    """
    n_levels = len(level_lists[0])
    if any(len(levels) != n_levels for levels in level_lists):
        raise ValueError("all pyramids must have the same number of levels")
    if mask_lists is None:
        mask_lists = [None] * len(level_lists)
    blended, any_valid = [], None
    for k in range(n_levels):
        inputs = [levels[k] for levels in level_lists]
        masks = [None if ml is None else ml[k] for ml in mask_lists]
        fb = None if fallback_levels is None else fallback_levels[k]
        if signed_lowpass and k == n_levels - 1:
            level, ok = _signed_dpa(inputs, masks, lam, fb)
        else:
            level, ok = detail_preserving_average(inputs, masks, lam, fb)
        blended.append(level)
        any_valid = ok if k == 0 else any_valid
    return collapse(blended, wrap_x=wrap_x), any_valid


@meta_shape_cache
def fresnel_combine(reflection_srgb: torch.Tensor, refraction_srgb: torch.Tensor, R, mask=None) -> torch.Tensor:
    """Fresnel-weighted colour ``c = R (c_refl - c_refr) + c_refr``, computed in linear RGB.

    Args:
        reflection_srgb: ``(B, C, H, W)`` sRGB colours of the reflection.
        refraction_srgb: ``(B, C, H, W)`` sRGB colours of the refraction.
        R: reflectance ``(B, 1, H, W)`` or ``(H, W)`` (torch or numpy) in ``[0, 1]``.
        mask: where to combine (bool, ``(B, 1, H, W)`` or ``(H, W)``); default everywhere.

    Returns:
        sRGB ``(B, C, H, W)``; ``refraction_srgb`` itself (bit for bit) outside ``mask`` and where
        ``R = 0``.

    Examples:
        Half of white over black is linear 0.5, sRGB 0.7354; ``R = 0`` keeps the refraction:

        >>> white, black = torch.ones(1, 3, 1, 2), torch.zeros(1, 3, 1, 2)
        >>> out = fresnel_combine(white, black, [[0.5, 0.0]])
        >>> [round(float(v), 4) for v in out[0, 0, 0]]
        [0.7354, 0.0]
    """
    ref = refraction_srgb
    R = as_tensor(R, dtype=ref.dtype, device=ref.device)
    if R.ndim == 2:
        R = R[None, None]
    refl, refr = srgb_to_linear(reflection_srgb), srgb_to_linear(refraction_srgb)
    c = linear_to_srgb(R * (refl - refr) + refr)
    use = R != 0
    if mask is not None:
        use = use & as_mask(mask, ref)
    return torch.where(use, c, refraction_srgb)


def absorb(refraction_srgb: torch.Tensor, transmittance) -> torch.Tensor:
    """The refracted colour after its path through an absorbing medium: ``c · T`` in linear RGB
    (Beer–Lambert, ``T = exp(-σ L)`` per channel, :meth:`~snell_bench.optics.WarpSet.transmittance`).

    Args:
        refraction_srgb: ``(B, 3, H, W)`` sRGB colours of the refraction.
        transmittance: ``(H, W, 3)`` (numpy or torch, channels last) or ``(B, 3, H, W)``, in ``[0, 1]``.

    Returns:
        sRGB ``(B, 3, H, W)``; ``refraction_srgb`` itself (bit for bit) where ``T = 1`` in every
        channel (outside the object, a clear material).

    Examples:
        Linear 0.5 of white is sRGB 0.7354; ``T = 1`` keeps the colour:

        >>> import numpy as np
        >>> white = torch.ones(1, 3, 1, 2)
        >>> T = np.array([[[0.5, 0.5, 0.5], [1.0, 1.0, 1.0]]], np.float32)
        >>> [round(float(v), 4) for v in absorb(white, T)[0, 0, 0]]
        [0.7354, 1.0]
    """
    ref = refraction_srgb
    T = as_tensor(transmittance, dtype=ref.dtype, device=ref.device)
    if T.ndim == 3:  # (H, W, 3) channels last
        T = T.permute(2, 0, 1)[None]
    tinted = linear_to_srgb(srgb_to_linear(ref) * T)
    return torch.where((T != 1).any(dim=1, keepdim=True), tinted, ref)

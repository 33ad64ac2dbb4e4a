"""How well a generated image shows what Snell's law fixes: the object region against π^R(I⁻)."""

from __future__ import annotations

import torch

from snell_bench.imaging.remap import remap
from snell_bench.metrics.functional import MetricUnavailable, masked_psnr
from snell_bench.utils.tensors import bchw_to_hwc

__all__ = ["refraction_psnr"]


def refraction_psnr(image: torch.Tensor, i_minus: torch.Tensor, warps) -> float | None:
    """PSNR (dB, RGB, no histogram matching) over the object pixels whose refracted ray I⁻
    observes, of ``image`` against π^R(I⁻).

    Args:
        image: ``(1, 3, H, W)`` sRGB generated image.
        i_minus: ``(1, 3, H, W)`` sRGB object-free image.
        warps: the :class:`~snell_bench.optics.warps.WarpSet` of the scene and object.

    Returns:
        The PSNR, ``inf`` for identical pixels, or ``None`` where no object pixel sees I⁻.
    """
    target, _ = remap(i_minus, warps.refraction)
    try:
        return masked_psnr(
            bchw_to_hwc(image),
            bchw_to_hwc(target),
            warps.object_mask & warps.refraction_valid,
            histogram_match=False,
            grayscale=False,
        )
    except MetricUnavailable:
        return None

"""A masked SSIM: scikit-image's structural similarity of the grayscale images, its map averaged
over the reference's metric mask (the pixels every snellcaster metric scores).

Registered by the entry point ``masked_ssim`` (``pyproject.toml``); ``metrics.extra=[masked_ssim]``
scores it for every cell, and every table, page and plot shows it as "SSIM (masked)".
"""

from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity

from snell_bench.metrics import MetricSpec, MetricUnavailable

__all__ = ["MASKED_SSIM", "masked_ssim"]

#: The luma weights (R, G, B) of the grayscale images.
GRAY = np.array([0.299, 0.587, 0.114])


def masked_ssim(x) -> float:
    """SSIM (Gaussian window, sigma 1.5, data range 1) of the grayscale generated image and
    reference, its map averaged over the metric mask.

    Args:
        x: the :class:`snell_bench.metrics.ScoreInputs` of one image.

    Raises:
        MetricUnavailable: an empty mask.
    """
    mask = np.asarray(x.mask, bool)
    if not mask.any():
        raise MetricUnavailable("empty mask: no object pixel refracts onto an observed surface")
    gen = np.asarray(x.generated, np.float64) @ GRAY
    ref = np.asarray(x.reference, np.float64) @ GRAY
    _, ssim = structural_similarity(
        gen, ref, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, full=True
    )
    return float(ssim[mask].mean())


MASKED_SSIM = MetricSpec(
    "masked_ssim",
    "SSIM (masked)",
    higher_is_better=True,
    format="{:.3f}",
    compute=masked_ssim,
    needs=("reference",),
    description="SSIM of the grayscale images (scikit-image, Gaussian window), averaged over the metric mask",
)

"""Filling the unknown pixels of an image smoothly from the known ones (push-pull).

Convention:
    Images are ``(B, C, H, W)`` float tensors, masks bool ``(H, W)`` or ``(B, 1, H, W)`` (true =
    known). ``wrap_x=True`` marks a 360° panorama, periodic in x. Known pixels are returned
    unchanged; an unknown pixel gets the normalised-convolution average of the known pixels around
    it at the finest pyramid level where it has any, so holes fill with a smooth continuation of
    their surroundings (no ground truth is used).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from snell_bench.utils.tensors import as_mask

__all__ = ["push_pull_fill"]


def _down(x: torch.Tensor, wrap_x: bool) -> torch.Tensor:
    if wrap_x and x.shape[-1] % 2:
        x = torch.cat([x, x[..., :1]], dim=-1)
    k = (2 if x.shape[-2] > 1 else 1, 2 if x.shape[-1] > 1 else 1)
    return F.avg_pool2d(x, k, ceil_mode=True, count_include_pad=False)


def push_pull_fill(image: torch.Tensor, known, *, wrap_x: bool = False, max_levels: int = 12) -> torch.Tensor:
    """``image`` with its unknown pixels filled from the known ones.

    Args:
        image: ``(B, C, H, W)`` float.
        known: where ``image`` is known, ``(H, W)`` or ``(B, 1, H, W)``.
        wrap_x: the image is periodic in x (an equirectangular panorama).
        max_levels: the coarsest pyramid level used (2^levels pixels per side).

    Returns:
        The filled image, ``image`` itself (bit for bit) where ``known``; where no pixel is known
        at all, the result is 0.

    Examples:
        >>> img = torch.tensor([[[[1.0, 0.0, 0.0, 3.0]]]])
        >>> known = torch.tensor([[True, False, False, True]])
        >>> push_pull_fill(img, known)[0, 0, 0].tolist()
        [1.0, 1.5, 2.5, 3.0]
    """
    m = as_mask(known, image).to(image.dtype).expand(image.shape[0], 1, *image.shape[-2:])
    # push: known-weighted averages down the pyramid
    vals, weights = [image * m], [m]
    while len(vals) <= max_levels and max(vals[-1].shape[-2:]) > 1:
        vals.append(_down(vals[-1], wrap_x))
        weights.append(_down(weights[-1], wrap_x))
    # pull: from the coarsest level up, unknown pixels take the coarser level's estimate
    est = vals[-1] / weights[-1].clamp_min(1e-12)
    for v, w in zip(reversed(vals[:-1]), reversed(weights[:-1])):
        up = F.interpolate(est, size=v.shape[-2:], mode="bilinear", align_corners=False)
        est = torch.where(w > 0, v / w.clamp_min(1e-12), up)
    return torch.where(m > 0, image, est)

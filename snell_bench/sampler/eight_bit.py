"""8-bit round trips of images, as an image library's 8-bit path rounds them.

Convention:
    Images: float tensors of any shape, sRGB in [0, 1]; results are float32 multiples of ``1 / 255``
    in [0, 1] on the input's device. Two roundings, as the authors' code applies them every step:
    decoded estimates pass diffusers' ``VaeImageProcessor.postprocess(..., "pil")`` (``round(255 x)``),
    synchronised images their ``tensor_to_pil`` (``uint8(255 x)``: truncation, NaN -> 0); both clamp to
    [0, 1] first and are read back as ``u / 255``.
"""

from __future__ import annotations

import torch

__all__ = ["to_8bit_floor", "to_8bit_round"]


def to_8bit_round(img: torch.Tensor) -> torch.Tensor:
    """``round(255 clamp(x, 0, 1)) / 255`` (round half to even, as numpy's ``round``); NaN -> 0.

    Examples:
        >>> to_8bit_round(torch.tensor([0.0, 0.5, 1.0 / 510, 1.0, 2.0])).mul(255).tolist()
        [0.0, 128.0, 0.0, 255.0, 255.0]
    """
    x = torch.nan_to_num(img.float(), nan=0.0).clamp(0.0, 1.0)
    return torch.round(x * 255.0) / 255.0


def to_8bit_floor(img: torch.Tensor) -> torch.Tensor:
    """``floor(255 clamp(x, 0, 1)) / 255``; NaN -> 0.

    Examples:
        >>> to_8bit_floor(torch.tensor([0.0, 0.5, 0.999, 1.0, float("nan")])).mul(255).tolist()
        [0.0, 127.0, 254.0, 255.0, 0.0]
    """
    x = torch.nan_to_num(img.float(), nan=0.0).clamp(0.0, 1.0)
    return torch.floor(x * 255.0) / 255.0

"""sRGB <-> linear RGB (IEC 61966-2-1 piecewise transfer function).

Convention:
    Values in [0, 1] (inputs are clamped there), any shape; numpy arrays or torch tensors in, the
    same kind out.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["srgb_to_linear", "linear_to_srgb"]


def srgb_to_linear(x):
    """Decode sRGB values to linear RGB.

    Args:
        x: sRGB values (numpy array, scalar or torch tensor), clamped to [0, 1].

    Returns:
        Linear values of the same shape and kind.

    Examples:
        >>> round(float(srgb_to_linear(0.5)), 4), round(float(srgb_to_linear(0.04)), 6)
        (0.214, 0.003096)
        >>> round(float(linear_to_srgb(srgb_to_linear(0.3))), 4)
        0.3
    """
    if isinstance(x, torch.Tensor):
        x = x.clamp(0.0, 1.0)
        return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x):
    """Encode linear RGB values to sRGB.

    Args:
        x: linear values (numpy array, scalar or torch tensor), clamped to [0, 1].

    Returns:
        sRGB values of the same shape and kind.

    Examples:
        >>> round(float(linear_to_srgb(0.5)), 4)
        0.7354
        >>> t = torch.tensor([0.0, 0.25, 1.0])
        >>> [round(float(v), 4) for v in srgb_to_linear(linear_to_srgb(t))]
        [0.0, 0.25, 1.0]
    """
    if isinstance(x, torch.Tensor):
        x = x.clamp(0.0, 1.0)
        return torch.where(x <= 0.0031308, x * 12.92, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055)

"""sRGB <-> linear RGB (IEC 61966-2-1 piecewise transfer function).

Convention: values in [0, 1] (inputs are clamped there), any shape; numpy arrays or torch tensors
in, the same kind out.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["srgb_to_linear", "linear_to_srgb"]


def srgb_to_linear(x):
    """Decode sRGB values to linear RGB."""
    if isinstance(x, torch.Tensor):
        x = x.clamp(0.0, 1.0)
        return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x):
    """Encode linear RGB values to sRGB."""
    if isinstance(x, torch.Tensor):
        x = x.clamp(0.0, 1.0)
        return torch.where(x <= 0.0031308, x * 12.92, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055)

"""Sampling images through backward warps (single level; kornia's ``remap``).

Convention
----------
- ``image``: float tensor ``(B, C, H, W)``.
- ``coords``: ``(H', W', 2)`` or ``(B, H', W', 2)`` source pixel coordinates ``(x, y)`` with integer
  values at pixel centres, NaN where the warp is invalid (numpy or torch).
- Returns ``(warped (B, C, H', W'), valid (B, H', W') bool)``; invalid pixels are 0.
- ``wrap_x=True`` treats the source as a 360° panorama: x wraps around (no seam at the border).
"""

from __future__ import annotations

import numpy as np
import torch
from kornia.geometry.transform import remap as _kornia_remap

__all__ = ["remap"]


def remap(image: torch.Tensor, coords, *, wrap_x: bool = False, mode: str = "bilinear") -> tuple[torch.Tensor, torch.Tensor]:
    if image.ndim != 4:
        raise ValueError(f"image must be (B, C, H, W), got shape {tuple(image.shape)}")
    c = torch.as_tensor(np.asarray(coords) if not isinstance(coords, torch.Tensor) else coords)
    c = c.to(device=image.device, dtype=image.dtype)
    if c.ndim == 3:
        c = c.unsqueeze(0)
    if c.ndim != 4 or c.shape[-1] != 2:
        raise ValueError(f"coords must be (H, W, 2) or (B, H, W, 2), got shape {tuple(c.shape)}")
    B = image.shape[0]
    if c.shape[0] == 1 and B > 1:
        c = c.expand(B, -1, -1, -1)
    H, W = image.shape[-2:]
    valid = torch.isfinite(c).all(-1)
    x = torch.where(valid, c[..., 0], torch.zeros_like(c[..., 0]))
    y = torch.where(valid, c[..., 1], torch.zeros_like(c[..., 1]))
    src = image
    if wrap_x:
        # one wrapped column on each side so that bilinear taps across the seam are right
        src = torch.cat([image[..., -1:], image, image[..., :1]], dim=-1)
        x = torch.remainder(x + 0.5, W) - 0.5 + 1.0
    else:
        valid = valid & (x >= -0.5) & (x <= W - 0.5)
    valid = valid & (y >= -0.5) & (y <= H - 0.5)
    # clamp the half-pixel border onto the outermost centres (edge extension)
    x = x.clamp(0.0, src.shape[-1] - 1.0)
    y = y.clamp(0.0, H - 1.0)
    out = _kornia_remap(src, x, y, mode=mode, padding_mode="border", align_corners=True)
    return out * valid[:, None].to(out.dtype), valid

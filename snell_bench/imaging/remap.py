"""Sampling images through backward warps (single level; kornia's ``remap``).

Convention:
    - ``image``: float tensor ``(B, C, H, W)``.
    - ``coords``: ``(H', W', 2)`` or ``(B, H', W', 2)`` source pixel coordinates ``(x, y)`` with
      integer values at pixel centres, NaN where the warp is invalid (numpy or torch).
    - Returns ``(warped (B, C, H', W'), valid (B, H', W') bool)``; invalid pixels are 0.
    - ``wrap_x=True`` treats the source as a 360° panorama: x wraps around (no seam at the border).
    - At a pixel centre (integer ``x`` and ``y``) the result is the source's value bit for bit, so an
      identity map, or an integer shift, returns the source's values.
"""

from __future__ import annotations

import torch
from kornia.geometry.transform import remap as _kornia_remap

from snell_bench.utils.tensors import as_tensor, is_meta

__all__ = ["remap"]


def remap(
    image: torch.Tensor, coords, *, wrap_x: bool = False, mode: str = "bilinear"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample ``image`` at the source coordinates of every destination pixel.

    A coordinate is valid where it is finite and inside the image area (``[-0.5, W - 0.5]`` x
    ``[-0.5, H - 0.5]``; x unbounded with ``wrap_x``); the half-pixel border repeats the outermost
    pixels.

    Args:
        image: ``(B, C, H, W)`` source image.
        coords: ``(H', W', 2)`` or ``(B, H', W', 2)`` source coordinates ``(x, y)``, NaN where
            invalid (numpy or torch; one map is shared by the batch).
        wrap_x: the source is a 360° panorama (x wraps around).
        mode: ``"bilinear"`` or ``"nearest"`` (kornia's interpolation modes).

    Returns:
        ``(warped (B, C, H', W'), valid (B, H', W') bool)``; invalid pixels are 0.

    Raises:
        ValueError: ``image`` is not 4-D or ``coords`` has a wrong shape.

    Examples:
        The identity map gives the image back, and half-way between two pixels their mean:

        >>> import numpy as np
        >>> img = torch.tensor([[[[0.0, 1.0], [2.0, 3.0]]]])
        >>> ys, xs = np.mgrid[0:2, 0:2].astype(np.float32)
        >>> out, valid = remap(img, np.stack([xs, ys], -1))
        >>> out[0, 0].tolist(), bool(valid.all())
        ([[0.0, 1.0], [2.0, 3.0]], True)
        >>> out, valid = remap(img, np.array([[[0.5, 0.0], [np.nan, 0.0], [2.0, 0.0]]]))
        >>> out[0, 0].tolist(), valid[0].tolist()
        ([[0.5, 0.0, 0.0]], [[True, False, False]])
        >>> out, _ = remap(img, np.array([[[2.0, 0.0]]]), wrap_x=True)  # x = 2 is x = 0 again
        >>> out[0, 0].tolist()
        [[0.0]]
    """
    if image.ndim != 4:
        raise ValueError(f"image must be (B, C, H, W), got shape {tuple(image.shape)}")
    c = as_tensor(coords, dtype=image.dtype, device=image.device)
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
    out = _exact_at_centres(out, src, x, y)
    return out * valid[:, None].to(out.dtype), valid


def _exact_at_centres(out: torch.Tensor, src: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``out`` with the source's own values, bit for bit, wherever ``(x, y)`` ``(B, H', W')`` (clamped
    into ``src``) is a pixel centre. kornia normalises coordinates to ``[-1, 1]`` and grid_sample maps
    them back, which moves an integer coordinate by rounding: the bilinear weights become ``1 - e``
    and ``e``, and an identity map changed about half of an image's values in the last bits."""
    exact = (x == x.floor()) & (y == y.floor())
    if not is_meta(exact) and not bool(exact.any()):
        return out
    B, C = out.shape[:2]
    s = src if src.shape[0] == B else src.expand(B, -1, -1, -1)
    idx = torch.where(exact, y.long() * src.shape[-1] + x.long(), torch.zeros_like(x, dtype=torch.long))
    picked = s.flatten(2).gather(2, idx.flatten(1)[:, None].expand(-1, C, -1)).view_as(out)
    return torch.where(exact[:, None], picked, out)

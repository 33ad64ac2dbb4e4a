"""Tensor layouts and shape checks, in the style of kornia's ``KORNIA_CHECK_SHAPE``.

Convention: images are float32 ``(B, C, H, W)`` tensors (torch) or ``(H, W, C)`` / ``(H, W)``
arrays (numpy); masks are boolean ``(H, W)``.

Examples:
    >>> import numpy as np
    >>> x = hwc_to_bchw(np.zeros((4, 6, 3)))
    >>> tuple(x.shape), x.dtype
    ((1, 3, 4, 6), torch.float32)
    >>> bchw_to_hwc(x).shape
    (4, 6, 3)
    >>> check_shape(x, ["B", "3", "H", "W"])
    >>> check_shape(x, ["B", "1", "H", "W"])
    Traceback (most recent call last):
    ...
    ValueError: tensor: expected shape ['B', '1', 'H', 'W'], got (1, 3, 4, 6)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

__all__ = ["as_tensor", "as_mask", "hwc_to_bchw", "bchw_to_hwc", "check_shape"]


def as_tensor(x, *, dtype: torch.dtype | None = None, device: torch.device | str | None = None) -> torch.Tensor:
    """``x`` (a tensor, a numpy array or anything ``np.asarray`` takes) as a tensor; a tensor is
    returned as it is when ``dtype`` and ``device`` already match."""
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    if dtype is not None or device is not None:
        t = t.to(dtype=dtype or t.dtype, device=device or t.device)
    return t


def hwc_to_bchw(img, *, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """``(H, W, C)`` (or ``(H, W)``) array or tensor -> ``(1, C, H, W)`` tensor (contiguous copy
    of a numpy input)."""
    a = img if isinstance(img, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(img))
    if a.ndim == 2:
        a = a[..., None]
    check_shape(a, ["H", "W", "C"], "image")
    return a.permute(2, 0, 1)[None].to(dtype)


def bchw_to_hwc(t: torch.Tensor, index: int = 0) -> np.ndarray:
    """Image ``index`` of a ``(B, C, H, W)`` tensor as an ``(H, W, C)`` numpy array (on the CPU)."""
    check_shape(t, ["B", "C", "H", "W"], "image")
    return t[index].detach().permute(1, 2, 0).cpu().numpy()


def check_shape(x, shape: Sequence[str], name: str = "tensor") -> None:
    """Raise ``ValueError`` unless ``x.shape`` fits ``shape``: digits must match exactly, any other
    entry (a letter such as ``"H"``) matches any size, and ``"*"`` as the first entry matches any
    number of leading dimensions."""
    dims = tuple(x.shape)
    want = list(shape)
    if want and want[0] == "*":
        want = want[1:]
        dims_tail = dims[len(dims) - len(want) :] if len(dims) >= len(want) else None
    else:
        dims_tail = dims if len(dims) == len(want) else None
    ok = dims_tail is not None and all(not w.isdigit() or int(w) == d for w, d in zip(want, dims_tail))
    if not ok:
        raise ValueError(f"{name}: expected shape {list(shape)}, got {dims}")


def as_mask(mask, like: torch.Tensor) -> torch.Tensor:
    """A mask in the layout of the imaging functions: ``(B or 1, 1, H, W)`` bool.

    Args:
        mask: ``(H, W)``, ``(B, H, W)`` or ``(B, 1, H, W)`` array or tensor (any dtype; nonzero is
            true).
        like: a tensor on the device the mask is wanted on.

    Returns:
        The mask as a bool ``(B or 1, 1, H, W)`` tensor on ``like``'s device.

    Raises:
        ValueError: ``mask`` has another shape.

    Examples:
        >>> m = as_mask(np.eye(3), torch.zeros(1, 3, 3, 3))
        >>> tuple(m.shape), m.dtype, int(m.sum())
        ((1, 1, 3, 3), torch.bool, 3)
    """
    m = as_tensor(mask, device=like.device)
    m = m.bool()
    if m.ndim == 2:
        m = m[None, None]
    elif m.ndim == 3:
        m = m[:, None]
    if m.ndim != 4 or m.shape[1] != 1:
        raise ValueError(f"mask must be (H, W) or (B, 1, H, W), got shape {tuple(m.shape)}")
    return m

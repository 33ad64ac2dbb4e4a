"""Tensor layouts and shape checks, in the style of kornia's ``KORNIA_CHECK_SHAPE``.

Convention: images are float32 ``(B, C, H, W)`` tensors (torch) or ``(H, W, C)`` / ``(H, W)``
arrays (numpy); masks are boolean ``(H, W)``. A tensor on the ``meta`` device has a shape and a
dtype but no values (:func:`is_meta`): code that reads values on the host (a window found from a
mask, a branch on ``mask.all()``) takes its general path there, with the same output shapes, and
a pure function whose outputs' shapes follow from its inputs' runs once per shape
(:func:`meta_shape_cache`).

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

import functools
import hashlib
from collections import OrderedDict
from collections.abc import Callable, Sequence

import numpy as np
import torch

__all__ = [
    "as_tensor",
    "digest",
    "as_mask",
    "hwc_to_bchw",
    "bchw_to_hwc",
    "check_shape",
    "is_meta",
    "meta_shape_cache",
    "to_host",
]


def as_tensor(x, *, dtype: torch.dtype | None = None, device: torch.device | str | None = None) -> torch.Tensor:
    """``x`` (a tensor, a numpy array or anything ``np.asarray`` takes) as a tensor; a tensor is
    returned as it is when ``dtype`` and ``device`` already match."""
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    if dtype is not None or device is not None:
        t = t.to(dtype=dtype or t.dtype, device=device or t.device)
    return t


def digest(x: torch.Tensor) -> str | None:
    """``"sha256:<hex>"`` of a tensor's values as contiguous float32 bytes on the host (``None`` on
    the ``meta`` device): two draws compare equal exactly when every value is bit-identical, so a
    record can show that two samplers started from the same noise."""
    if is_meta(x):
        return None
    data = x.detach().to("cpu", torch.float32).contiguous().numpy().tobytes()
    return "sha256:" + hashlib.sha256(data).hexdigest()


def is_meta(x: torch.Tensor | torch.device | str) -> bool:
    """Whether ``x`` (a tensor or a device) is on the ``meta`` device: shapes and dtypes, no data,
    so no value can be read on the host.

    Examples:
        >>> is_meta(torch.empty(2, device="meta")), is_meta(torch.zeros(2)), is_meta("meta")
        (True, False, True)
    """
    device = x.device if isinstance(x, torch.Tensor) else torch.device(x)
    return device.type == "meta"


def to_host(x: torch.Tensor | None) -> torch.Tensor | None:
    """``x`` on the CPU (``None`` stays ``None``); a :func:`is_meta` tensor stays on ``meta``, as it
    has no data to copy.

    Examples:
        >>> to_host(torch.empty(2, device="meta")).device, to_host(torch.zeros(2)).device
        (device(type='meta'), device(type='cpu'))
    """
    return x if x is None or is_meta(x) else x.cpu()


class _Uncacheable(Exception):
    """An argument that :func:`meta_shape_cache` cannot key by value."""


def _shape_key(x, found: list[bool]):
    """A hashable key of ``x`` that holds tensors and arrays by shape and dtype, random generators by
    device and everything else by value (``found[0]`` set when a ``meta`` tensor is met)."""
    if isinstance(x, torch.Tensor):
        found[0] = found[0] or is_meta(x)
        return ("tensor", tuple(x.shape), x.dtype, x.device.type)
    if isinstance(x, np.ndarray):
        return ("array", x.shape, x.dtype.str)
    if isinstance(x, (list, tuple)):
        return (type(x).__name__,) + tuple(_shape_key(v, found) for v in x)
    if isinstance(x, dict):
        return ("dict",) + tuple((k, _shape_key(v, found)) for k, v in sorted(x.items()))
    if x is None or isinstance(x, (bool, int, float, str, torch.dtype, torch.device)):
        return x
    if isinstance(x, torch.Generator):  # its state decides values, not shapes
        return ("generator", x.device.type)
    raise _Uncacheable(type(x).__name__)


def _shape_spec(out):
    """``out`` with every tensor replaced by its shape, dtype and device (:func:`_from_spec` makes
    empty ones again)."""
    if isinstance(out, torch.Tensor):
        return ("tensor", tuple(out.shape), out.dtype, out.device)
    if isinstance(out, (list, tuple)):
        return (type(out), [_shape_spec(v) for v in out])
    return ("value", out)


def _from_spec(spec):
    if spec[0] == "tensor":
        return torch.empty(spec[1], dtype=spec[2], device=spec[3])
    if spec[0] == "value":
        return spec[1]
    return spec[0](_from_spec(v) for v in spec[1])


def meta_shape_cache(fn: Callable | None = None, *, maxsize: int = 1024) -> Callable:
    """Decorate a function whose outputs' shapes follow from its arguments': called with a ``meta``
    tensor among them, it runs once per key (every tensor's and array's shape and dtype, a random
    generator's device, every other argument's value) and later calls get new empty tensors of the
    first call's output shapes, dtypes and devices. Without a ``meta`` tensor (or with an argument
    it cannot key) the function runs as it is.

    On ``meta`` an operation costs its Python dispatch alone (~0.1 ms, ~10 ms for ``grid_sample``),
    so a loop of many identical steps spends its time repeating shape propagation; the first call
    of each key still runs the function's real (general) path.

    Args:
        fn: the function (the decorator also works as ``meta_shape_cache(maxsize=...)``).
        maxsize: keys kept, least recently used dropped first.

    Examples:
        >>> calls = []
        >>> @meta_shape_cache
        ... def double(x, times=2):
        ...     calls.append(1)
        ...     return x.repeat(times, 1)
        >>> [tuple(double(torch.empty(1, 3, device="meta")).shape) for _ in range(3)], len(calls)
        ([(2, 3), (2, 3), (2, 3)], 1)
        >>> tuple(double(torch.empty(1, 3, device="meta"), times=3).shape), len(calls)
        ((3, 3), 2)
        >>> double(torch.ones(1, 2)).tolist(), len(calls)
        ([[1.0, 1.0], [1.0, 1.0]], 3)
    """
    if fn is None:
        return functools.partial(meta_shape_cache, maxsize=maxsize)
    cache: OrderedDict = OrderedDict()

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        found = [False]
        try:
            key = _shape_key((args, kwargs), found)
        except _Uncacheable:
            return fn(*args, **kwargs)
        if not found[0]:
            return fn(*args, **kwargs)
        if key not in cache:
            cache[key] = _shape_spec(fn(*args, **kwargs))
            if len(cache) > maxsize:
                cache.popitem(last=False)
        cache.move_to_end(key)
        return _from_spec(cache[key])

    return wrapper


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

"""Counting the bytes that cross between devices (host <-> GPU) while a block of code runs.

Convention: every tensor copy whose source and destination devices differ (``Tensor.to``,
``.cuda()``, ``.cpu()``, ``copy_`` across devices) is counted once, by the bytes of the source,
keyed ``"<src>-><dst>"`` by device type (``"cpu->cuda"``); reading a scalar on the host
(``.item()``, ``bool(t)``, ``int(t)``) is counted as a sync. Copies within one device are not
counted. It is a :class:`~torch.utils._python_dispatch.TorchDispatchMode`, so it sees every
operator call under it, including inside libraries (kornia, diffusers).

Examples:
    >>> import torch
    >>> x = torch.zeros(4, 4)
    >>> with TransferCounter() as moved:
    ...     _ = x.to("meta")          # a second device: 64 bytes leave the CPU
    ...     _ = (x + 1).sum().item()  # a scalar read on the host
    >>> moved.bytes, moved.by_direction, moved.syncs
    (64, {'cpu->meta': 64}, 1)
"""

from __future__ import annotations

import torch
from torch.utils._python_dispatch import TorchDispatchMode

__all__ = ["TransferCounter"]

_aten = torch.ops.aten
_COPIES_FROM_ARG0 = {_aten._to_copy.default}  # (src, ...) -> a new tensor
_COPIES_FROM_ARG1 = {_aten.copy_.default, _aten._copy_from.default, _aten._copy_from_and_resize.default}
_SCALAR_READS = {_aten._local_scalar_dense.default, _aten.is_nonzero.default}


class TransferCounter(TorchDispatchMode):
    """Counts cross-device bytes (:attr:`bytes`, :attr:`by_direction`) and host scalar reads
    (:attr:`syncs`) of the operators run inside ``with TransferCounter() as moved:``."""

    def __init__(self) -> None:
        super().__init__()
        self.bytes = 0
        self.by_direction: dict[str, int] = {}
        self.syncs = 0

    def _count(self, src: torch.Tensor, dst_device: torch.device) -> None:
        if src.device.type == dst_device.type and src.device == dst_device:
            return
        n = src.numel() * src.element_size()
        key = f"{src.device.type}->{dst_device.type}"
        self.bytes += n
        self.by_direction[key] = self.by_direction.get(key, 0) + n

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        out = func(*args, **kwargs)
        if func in _COPIES_FROM_ARG0 and isinstance(out, torch.Tensor):
            self._count(args[0], out.device)
        elif func in _COPIES_FROM_ARG1:
            dst, src = args[0], args[1]
            if isinstance(src, torch.Tensor) and isinstance(dst, torch.Tensor):
                self._count(src, dst.device)
        elif func in _SCALAR_READS:
            self.syncs += 1
        return out

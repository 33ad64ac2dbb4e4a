"""Devices and dtypes for the model backends: one parser for dtype names, the device a backend runs
on, the default precision per device, and diffusers' dtype keyword.

Convention:
    - A device is ``None`` / ``"auto"`` (CUDA, which must be available), ``"cuda[:i]"`` (likewise)
      or any other torch device, e.g. ``"cpu"``, which is used as it is.
    - A dtype is given as ``None`` (the backend's default), a :class:`torch.dtype`, or one of the
      names in :data:`DTYPE_NAMES` (case-insensitive, optionally prefixed with ``torch.``).
    - The default precision is bfloat16 on CUDA and float32 elsewhere.
    - Only torch is imported here, so ``import snell_bench.models`` stays light.
"""

from __future__ import annotations

import torch

from snell_bench.config.choices import DTYPE_NAMES as CONFIG_DTYPE_NAMES

from .errors import DeviceNotAvailableError

__all__ = ["DTYPE_NAMES", "default_dtype", "dtype_kwarg", "parse_dtype", "resolve_device"]

#: Accepted dtype names -> dtype (the names are the config's, :data:`snell_bench.config.choices.DTYPE_NAMES`).
DTYPE_NAMES: dict[str, torch.dtype] = {name: getattr(torch, dt) for name, dt in CONFIG_DTYPE_NAMES.items()}


def _accepted() -> str:
    groups: dict[torch.dtype, list[str]] = {}
    for name, dt in DTYPE_NAMES.items():
        groups.setdefault(dt, []).append(name)
    return "; ".join(" / ".join(names) for names in groups.values())


def parse_dtype(dtype: torch.dtype | str | None) -> torch.dtype | None:
    """A dtype from its name (``"bfloat16"``, ``"bf16"``, ``"torch.float32"``, ...).

    Args:
        dtype: ``None``, a :class:`torch.dtype` (returned as it is), or a name from
            :data:`DTYPE_NAMES`, case-insensitive, with or without a ``torch.`` prefix.

    Returns:
        The dtype, or ``None`` for ``None`` (the caller's default applies).

    Raises:
        ValueError: for an unknown name (the message lists the accepted names and names the
            config key ``model.dtype``).
        TypeError: for anything that is neither ``None``, a dtype nor a string.

    Examples:
        >>> parse_dtype("bf16"), parse_dtype("torch.float32"), parse_dtype(None)
        (torch.bfloat16, torch.float32, None)
    """
    if dtype is None or isinstance(dtype, torch.dtype):
        return dtype
    if not isinstance(dtype, str):
        raise TypeError(f"dtype must be None, a torch.dtype or a name, got {type(dtype).__name__} {dtype!r}")
    name = dtype.strip().lower().removeprefix("torch.")
    if name not in DTYPE_NAMES:
        raise ValueError(
            f"unknown dtype {dtype!r} (config key model.dtype); use one of: {_accepted()} "
            "(optionally prefixed with 'torch.')"
        )
    return DTYPE_NAMES[name]


def resolve_device(device: str | torch.device | None, *, unavailable: str) -> torch.device:
    """The device to run on: CUDA unless another device is asked for explicitly.

    Args:
        device: ``None`` or ``"auto"`` (CUDA), ``"cuda[:i]"``, ``"cpu"``, or a :class:`torch.device`.
        unavailable: the message of the error raised when CUDA is needed and missing (it should
            say which config key or argument selects the CPU instead).

    Returns:
        The device.

    Raises:
        DeviceNotAvailableError: if CUDA is asked for (explicitly or by default) and missing.
    """
    if device is None or str(device) == "auto":
        device = "cuda"
    dev = torch.device(device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise DeviceNotAvailableError(unavailable)
    return dev


def default_dtype(device: torch.device | str) -> torch.dtype:
    """bfloat16 on CUDA, float32 on any other device."""
    return torch.bfloat16 if torch.device(device).type == "cuda" else torch.float32


def dtype_kwarg(dtype: torch.dtype) -> dict:
    """The dtype keyword of diffusers' ``from_pretrained``.

    Args:
        dtype: the dtype to load the weights in.

    Returns:
        ``{"dtype": dtype}`` for diffusers >= 0.42 (where ``torch_dtype=`` is deprecated), else
        ``{"torch_dtype": dtype}``.
    """
    try:
        from diffusers.utils.deprecation_utils import _resolve_dtype  # noqa: F401
    except ImportError:
        return {"torch_dtype": dtype}
    return {"dtype": dtype}

"""Generators (the model backends) behind one protocol, and a registry that builds them by name.

Convention:
    - Every backend implements :class:`~snell_bench.models.base.Generator` (see its docstring for the
      image, latent, flow-matching and randomness conventions).
    - Backends are registered as ``"module:attribute"`` import paths and imported only when built, so
      ``import snell_bench.models`` never imports diffusers or transformers, and a backend whose
      module is missing does not break the others.
    - Names: ``flux`` / ``flux_dev`` (FLUX.1-dev from local weights, keyword ``path`` or
      ``model_id_or_path``), ``tiny_flux`` (random toy FLUX, CPU), ``analytic`` (CPU, no weights).
    - Dtypes are given as a ``torch.dtype`` or a name that :func:`parse_dtype` reads
      (``"bfloat16"`` / ``"bf16"``, ``"float16"`` / ``"fp16"`` / ``"half"``, ``"float32"`` / ``"fp32"``).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from .base import SCHEDULES, Condition, Generator, LatentGeometry
from .devices import parse_dtype
from .errors import DeviceNotAvailableError, WeightsNotFoundError

__all__ = [
    "SCHEDULES",
    "Condition",
    "DeviceNotAvailableError",
    "Generator",
    "LatentGeometry",
    "WeightsNotFoundError",
    "available_generators",
    "build_generator",
    "parse_dtype",
    "register_generator",
]

#: name -> "module:attribute" (a class or a factory called with the keyword arguments).
_REGISTRY: dict[str, str] = {
    "flux": "snell_bench.models:_build_flux",
    "flux_dev": "snell_bench.models:_build_flux",
    "tiny_flux": "snell_bench.models.tiny_flux:TinyFluxGenerator",
    "analytic": "snell_bench.models.analytic:AnalyticGenerator",
    "mixture": "snell_bench.models.mixture:scene_mixture",
}


def _build_flux(path: str | None = None, **kwargs: Any):
    """FLUX.1-dev via :meth:`FluxGenerator.from_pretrained`; ``path`` is the config's
    ``model.path`` (an alias of ``model_id_or_path``)."""
    from .flux import FluxGenerator

    if path is not None:
        if "model_id_or_path" in kwargs:
            raise TypeError("give either path or model_id_or_path, not both")
        kwargs["model_id_or_path"] = path
    return FluxGenerator.from_pretrained(**kwargs)


def register_generator(name: str, target: str | Callable[..., Any]) -> None:
    """Register a backend under ``name``: a ``"module:attribute"`` path or a callable."""
    _REGISTRY[name] = target  # type: ignore[assignment]


def _resolve(target: str | Callable[..., Any]) -> Callable[..., Any]:
    if callable(target):
        return target
    module_name, _, attr = target.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def available_generators() -> list[str]:
    """Registered names whose module can be found (without importing it)."""
    import importlib.util

    names = []
    for name, target in _REGISTRY.items():
        if callable(target):
            names.append(name)
            continue
        module_name = target.partition(":")[0]
        try:
            found = importlib.util.find_spec(module_name) is not None
        except ModuleNotFoundError:
            found = False
        if found:
            names.append(name)
    return sorted(names)


def build_generator(name: str, **kwargs: Any) -> Generator:
    """Build the generator registered as ``name`` with ``kwargs``.

    Args:
        name: a registered name (case-insensitive; ``-`` and ``_`` are the same).
        **kwargs: passed to the backend's class or factory.

    Returns:
        The generator.

    Raises:
        KeyError: for an unknown name.
        ImportError: when the backend's module is missing.
    """
    key = name.lower().replace("-", "_")
    if key not in _REGISTRY:
        raise KeyError(f"unknown generator {name!r}; registered: {sorted(_REGISTRY)}")
    target = _REGISTRY[key]
    try:
        factory = _resolve(target)
    except ModuleNotFoundError as err:
        if err.name != target.partition(":")[0]:
            raise
        raise ImportError(f"generator {name!r} is registered as {target!r}, but its module is missing: {err}") from err
    return factory(**kwargs)

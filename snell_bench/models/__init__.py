"""Generators (the model backends) behind one protocol, depth and segmentation models, and the
tiny random-weight models the tests run.

Convention:
    - Every generator implements :class:`~snell_bench.models.base.Generator` (see its docstring for
      the image, latent, flow-matching and randomness conventions).
    - A generator is built from its config node, ``hydra.utils.instantiate(cfg.model.generator)``:
      each ``conf/model/<name>.yaml`` names its backend's class or factory as ``_target_``
      (``model=flux_dev``: :meth:`~snell_bench.models.flux.FluxGenerator.from_pretrained`;
      ``model=tiny_flux``: :class:`~snell_bench.models.tiny_flux.TinyFluxGenerator`;
      ``model=analytic`` / ``model=mixture``: ``from_scene`` of
      :class:`~snell_bench.models.analytic.AnalyticGenerator` /
      :class:`~snell_bench.models.mixture.MixtureGenerator`), or from the class directly.
    - ``import snell_bench.models`` imports torch only: diffusers and transformers are imported when
      a model that needs them is built.
    - Dtypes are given as a ``torch.dtype`` or a name that :func:`parse_dtype` reads
      (``"bfloat16"`` / ``"bf16"``, ``"float16"`` / ``"fp16"`` / ``"half"``, ``"float32"`` / ``"fp32"``).
"""

from __future__ import annotations

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
    "parse_dtype",
]

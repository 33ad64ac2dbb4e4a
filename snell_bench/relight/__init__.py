"""Relighting, the paper's last stage: N relit candidates of the sampled image, the one closest to
it inside the object's silhouette kept (:func:`relight`).

Relighters (:class:`Relighter`):

- :class:`~snell_bench.relight.kontext.KontextRelighter`: FLUX.1 Kontext through diffusers, from
  local weights (``from_pretrained``) or the tiny random one (``tiny``), optionally with a LoRA;
- :class:`~snell_bench.relight.shadow.ShadowRelighter`: the CPU stand-in, a traced soft shadow of
  the object under a jittered directional light (no caustics, no light transport through the glass).

Convention: images are ``(1, 3, H, W)`` float32 sRGB tensors in [0, 1]; masks ``(H, W)`` bool. The
relighters' modules are imported on first use (``import snell_bench.relight`` imports neither
diffusers nor Open3D).
"""

from __future__ import annotations

import importlib
from typing import Any

from .base import Relighter, check_image
from .select import IDENTICAL_NOTE, RelightResult, candidate_seeds, masked_psnr, relight

__all__ = [
    "IDENTICAL_NOTE",
    "KontextRelighter",
    "RelightResult",
    "Relighter",
    "ShadowRelighter",
    "candidate_seeds",
    "check_image",
    "masked_psnr",
    "relight",
]

_LAZY = {"KontextRelighter": ".kontext", "ShadowRelighter": ".shadow"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

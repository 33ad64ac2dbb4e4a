"""The generator protocol every backend implements (analytic, FLUX, tiny FLUX).

Convention
----------
- Images: float32 tensors ``(B, 3, H, W)``, sRGB-encoded, in [0, 1].
- Latents: *unpacked* float tensors ``(B, C, h, w)`` with ``h = H / downscale``; a backend that
  packs latents internally (FLUX: ``(B, N, 4C)``) does so inside :meth:`Generator.velocity`.
- Flow matching (rectified flow): ``z_sigma = (1 - sigma) x0 + sigma eps``; the model's velocity
  is ``v = eps - x0``, so the Euler estimate of the clean latent is ``x0_hat = z - sigma v``.
- ``sigma``: a float or a ``(B,)`` tensor in (0, 1].
- Randomness comes only from the ``torch.Generator`` passed in (bitwise reproducible on CPU).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import torch

__all__ = ["Condition", "Generator", "LatentGeometry"]


@dataclass
class Condition:
    """Text conditioning for one or more prompts (batch dimension first in every tensor).

    ``data`` holds backend-specific tensors (FLUX: ``prompt_embeds``, ``pooled_prompt_embeds``,
    ``text_ids``; the analytic backend: which prior to use). ``prompts`` keeps the text.
    """

    prompts: list[str]
    data: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.prompts)


@dataclass(frozen=True)
class LatentGeometry:
    """How images map to latents: ``(C, H / downscale, W / downscale)``; image sizes must be
    multiples of ``multiple``."""

    channels: int
    downscale: int
    multiple: int

    def latent_shape(self, height: int, width: int) -> tuple[int, int, int]:
        if height % self.multiple or width % self.multiple:
            raise ValueError(
                f"image size {height}x{width} must be a multiple of {self.multiple} for this generator; "
                f"use e.g. {height // self.multiple * self.multiple}x{width // self.multiple * self.multiple}"
            )
        return (self.channels, height // self.downscale, width // self.downscale)


@runtime_checkable
class Generator(Protocol):
    """A flow-matching image generator with a latent space."""

    name: str
    geometry: LatentGeometry

    def encode(self, images: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """Images ``(B, 3, H, W)`` in [0, 1] -> latents ``(B, C, h, w)`` (deterministic: the
        distribution's mode, or a sample drawn from ``generator``)."""
        ...

    def decode(self, latents: torch.Tensor) -> torch.Tensor:
        """Latents ``(B, C, h, w)`` -> images ``(B, 3, H, W)`` in [0, 1]."""
        ...

    def condition(self, prompts: list[str], views: list[str]) -> Condition:
        """Prompt conditioning; ``views[i]`` is ``"main"`` or ``"pano"`` (backends may use it)."""
        ...

    def velocity(self, z: torch.Tensor, sigma, cond: Condition) -> torch.Tensor:
        """The flow-matching velocity ``(B, C, h, w)`` at noise level ``sigma``."""
        ...

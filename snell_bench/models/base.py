"""The generator protocol every backend implements (analytic, FLUX, tiny FLUX).

Convention:
    - Images: float32 tensors ``(B, 3, H, W)``, sRGB-encoded, in [0, 1].
    - Latents: *unpacked* float tensors ``(B, C, h, w)`` with ``h = H / downscale``; a backend that
      packs latents internally (FLUX: ``(B, N, 4C)``) does so inside :meth:`Generator.velocity`.
    - Flow matching (rectified flow): ``z_sigma = (1 - sigma) x0 + sigma eps``; the model's velocity
      is ``v = eps - x0``, so the Euler estimate of the clean latent is ``x0_hat = z - sigma v``.
    - ``sigma``: a float or a ``(B,)`` tensor in (0, 1].
    - Schedules: :meth:`Generator.sigmas` gives ``T + 1`` noise levels ``1 = sigma_0 > ... >
      sigma_T = 0`` (step ``i`` goes from ``sigmas[i]`` to ``sigmas[i + 1]``), of a kind in
      :data:`SCHEDULES`: ``"flux"`` (the backend's own resolution-shifted schedule) or ``"linear"``.
    - Randomness comes only from the ``torch.Generator`` passed in (bitwise reproducible on CPU).
    - Placement: a backend may have a ``device`` (where its tensors live; the CPU when absent) and a
      ``dtype`` (its precision; float32 when absent). Samplers keep every latent, noise draw, warp
      and blend on ``device`` (:func:`generator_device`); the backend's methods return tensors on
      their inputs' device.
    - Posterior: a backend may say ``has_posterior = False`` (its encoder is a deterministic map, so
      ``encode(..., generator)`` is the mean); absent, it is taken to have one
      (:func:`has_posterior`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import torch

from snell_bench.config.sampler import SCHEDULES as _SCHEDULES

__all__ = [
    "SCHEDULES",
    "Condition",
    "Generator",
    "LatentGeometry",
    "check_schedule",
    "generator_device",
    "has_posterior",
]

#: Schedule kinds every backend's :meth:`Generator.sigmas` accepts.
SCHEDULES = _SCHEDULES  # the ``sampler.schedule`` choices, owned by the schema


def check_schedule(kind: str, num_steps: int) -> None:
    """Validate the arguments of :meth:`Generator.sigmas`.

    Args:
        kind: the schedule kind, one of :data:`SCHEDULES`.
        num_steps: the number of denoising steps.

    Raises:
        ValueError: for an unknown kind or a step count that is not a positive integer.
    """
    if kind not in SCHEDULES:
        raise ValueError(f"unknown schedule {kind!r} (config key sampler.schedule); use one of {SCHEDULES}")
    if isinstance(num_steps, bool) or int(num_steps) != num_steps or num_steps < 1:
        raise ValueError(f"the number of steps must be a positive integer, got {num_steps!r}")


def generator_device(gen) -> torch.device:
    """Where ``gen``'s tensors live: its ``device`` attribute, the CPU when it has none.

    Examples:
        >>> generator_device(object())
        device(type='cpu')
    """
    return torch.device(getattr(gen, "device", None) or "cpu")


def has_posterior(gen) -> bool:
    """Whether ``gen.encode(images, generator)`` draws from a posterior (its ``has_posterior``
    attribute; ``True`` when absent).

    Examples:
        >>> has_posterior(object())
        True
    """
    return bool(getattr(gen, "has_posterior", True))


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
        """The latent shape ``(C, h, w)`` of an image of ``height x width`` pixels.

        Raises:
            ValueError: if the size is not a multiple of ``multiple``.
        """
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
        """Images ``(B, 3, H, W)`` in [0, 1] -> latents ``(B, C, h, w)``: the posterior's mean
        (mode) without ``generator``; with it, a draw from the posterior using only ``generator``
        (``sampler.encode=sample``). A backend whose encoder has no posterior (a deterministic map)
        returns the mean either way and leaves ``generator`` untouched."""
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

    def sigmas(self, num_steps: int, height: int, width: int, kind: str = "flux") -> torch.Tensor:
        """The noise schedule for sampling ``height x width`` images in ``num_steps`` steps.

        Args:
            num_steps: the number of denoising steps ``T`` (a positive integer).
            height: the image height in pixels (a multiple of ``geometry.multiple``).
            width: the image width in pixels.
            kind: ``"flux"`` (the backend's resolution-shifted schedule) or ``"linear"``
                (``1, 1 - 1/T, ..., 0``), see :data:`SCHEDULES`.

        Returns:
            A float CPU tensor ``(num_steps + 1,)`` (float64 in the backends here), decreasing
            from 1 to 0.

        Raises:
            ValueError: for an unknown kind, a bad step count or an image size the geometry rejects.
        """
        ...

"""Noise schedules for rectified-flow sampling.

Convention: a schedule is a float64 tensor of ``T + 1`` noise levels ``sigma_0 = 1 > ... > sigma_T = 0``
(step ``i`` goes from ``sigmas[i]`` to ``sigmas[i + 1]``).
"""

from __future__ import annotations

import math

import torch

__all__ = ["flux_shift", "flux_sigmas", "linear_sigmas", "make_sigmas"]


def flux_shift(
    image_seq_len: int,
    base_seq_len: int = 256,
    max_seq_len: int = 4096,
    base_shift: float = 0.5,
    max_shift: float = 1.15,
) -> float:
    """FLUX's resolution-dependent shift ``mu`` (linear in the number of packed latent tokens)."""
    m = (max_shift - base_shift) / (max_seq_len - base_seq_len)
    return image_seq_len * m + (base_shift - m * base_seq_len)


def linear_sigmas(num_steps: int) -> torch.Tensor:
    """``1, 1 - 1/T, ..., 1/T, 0``."""
    _check_steps(num_steps)
    return torch.linspace(1.0, 0.0, num_steps + 1, dtype=torch.float64)


def flux_sigmas(num_steps: int, image_seq_len: int, **shift_kwargs) -> torch.Tensor:
    """FLUX.1-dev's schedule: ``linspace(1, 1/T, T)`` time-shifted by
    ``sigma' = e^mu / (e^mu + 1/sigma - 1)`` with ``mu = flux_shift(image_seq_len)``, then 0."""
    _check_steps(num_steps)
    mu = flux_shift(image_seq_len, **shift_kwargs)
    s = torch.linspace(1.0, 1.0 / num_steps, num_steps, dtype=torch.float64)
    shifted = math.exp(mu) / (math.exp(mu) + (1.0 / s - 1.0))
    return torch.cat([shifted, torch.zeros(1, dtype=torch.float64)])


def make_sigmas(kind: str, num_steps: int, latent_hw: tuple[int, int]) -> torch.Tensor:
    """``kind``: ``"flux"`` (shifted for the latent size; tokens = (h/2)(w/2)) or ``"linear"``."""
    if kind == "flux":
        h, w = latent_hw
        return flux_sigmas(num_steps, (h // 2) * (w // 2))
    if kind == "linear":
        return linear_sigmas(num_steps)
    raise ValueError(f"unknown schedule {kind!r}; use 'flux' or 'linear'")


def _check_steps(num_steps: int) -> None:
    if int(num_steps) != num_steps or num_steps < 1:
        raise ValueError(f"the number of steps must be a positive integer, got {num_steps!r}")

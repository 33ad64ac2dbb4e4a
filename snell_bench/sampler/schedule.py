"""Closed forms of the rectified-flow noise schedules, in float64.

The sampler takes its schedule from the generator (:meth:`~snell_bench.models.base.Generator.sigmas`);
these closed forms are the analytic backend's implementation of it, the ``linear`` kind of every
backend, and an independent oracle for diffusers' scheduler in the tests.

Convention: a schedule is a float64 tensor of ``T + 1`` noise levels ``sigma_0 = 1 > ... > sigma_T = 0``
(step ``i`` goes from ``sigmas[i]`` to ``sigmas[i + 1]``).
"""

from __future__ import annotations

import math

import torch

__all__ = ["flux_shift", "flux_sigmas", "linear_sigmas"]


def flux_shift(
    image_seq_len: int,
    base_seq_len: int = 256,
    max_seq_len: int = 4096,
    base_shift: float = 0.5,
    max_shift: float = 1.15,
) -> float:
    """FLUX's resolution-dependent shift ``mu`` (linear in the number of packed latent tokens).

    Args:
        image_seq_len: the number of packed latent tokens, ``(h / 2) (w / 2)``.
        base_seq_len: the token count where ``mu = base_shift``.
        max_seq_len: the token count where ``mu = max_shift``.
        base_shift: ``mu`` at ``base_seq_len``.
        max_shift: ``mu`` at ``max_seq_len``.

    Returns:
        ``mu``.
    """
    m = (max_shift - base_shift) / (max_seq_len - base_seq_len)
    return image_seq_len * m + (base_shift - m * base_seq_len)


def linear_sigmas(num_steps: int) -> torch.Tensor:
    """The linear schedule ``1, 1 - 1/T, ..., 1/T, 0``.

    Args:
        num_steps: the number of steps ``T`` (a positive integer).

    Returns:
        A float64 tensor ``(T + 1,)``.

    Raises:
        ValueError: if ``num_steps`` is not a positive integer.
    """
    _check_steps(num_steps)
    return torch.linspace(1.0, 0.0, num_steps + 1, dtype=torch.float64, device="cpu")


def flux_sigmas(num_steps: int, image_seq_len: int, **shift_kwargs) -> torch.Tensor:
    """FLUX.1-dev's schedule: ``linspace(1, 1/T, T)`` time-shifted by
    ``sigma' = e^mu / (e^mu + 1/sigma - 1)`` with ``mu = flux_shift(image_seq_len)``, then 0.

    Args:
        num_steps: the number of steps ``T`` (a positive integer).
        image_seq_len: the number of packed latent tokens, ``(h / 2) (w / 2)``.
        **shift_kwargs: passed to :func:`flux_shift`.

    Returns:
        A float64 tensor ``(T + 1,)``.

    Raises:
        ValueError: if ``num_steps`` is not a positive integer.
    """
    _check_steps(num_steps)
    mu = flux_shift(image_seq_len, **shift_kwargs)
    s = torch.linspace(1.0, 1.0 / num_steps, num_steps, dtype=torch.float64, device="cpu")
    shifted = math.exp(mu) / (math.exp(mu) + (1.0 / s - 1.0))
    return torch.cat([shifted, torch.zeros(1, dtype=torch.float64, device="cpu")])


def _check_steps(num_steps: int) -> None:
    if int(num_steps) != num_steps or num_steps < 1:
        raise ValueError(f"the number of steps must be a positive integer, got {num_steps!r}")
